//! Stereo calibration at home on rendered fisheye pairs with truth: the four-board AprilGrid
//! scene seen by two OV8856-like cameras (slightly different intrinsics, 65 mm apart, a small
//! relative rotation) from 9 head orientations; both intrinsics (fisheye model) and T_lH^rH must
//! come back close to the truth the images were rendered with.
use abvs_camcal::detect::{detect, gray_mat, AprilDetector};
use abvs_camcal::intrinsics::{CalibOptions, Model};
use abvs_camcal::render_grid::{to_iso_m, GridScene};
use abvs_camcal::stereo::calibrate_stereo;
use abvs_camcal::target::{AprilGridSpec, Target};
use abvs_camera::Camera;
use abvs_eye::pose::rotation_angle_deg;
use abvs_eye::{Fick, Pose};
use abvs_render::{RayTable, RenderOptions};
use nalgebra::{Matrix3, Vector3};

#[test]
fn stereo_at_home_from_rendered_fisheye_pairs() {
    let left = Camera::ov8856();
    let right = Camera { fx: left.fx * 1.004, fy: left.fy * 1.004, cx: left.cx + 3.0, cy: left.cy - 2.0, ..left };
    // x_r = R x_l + T (mm)
    let r_true: Matrix3<f64> = Fick::from_deg([0.3, -0.2, 0.4]).to_matrix();
    let t_true = Vector3::new(-65.0, 0.6, -0.4);
    let right_in_left = Pose::new(r_true.transpose(), -(r_true.transpose() * t_true));
    let grid = GridScene::paper(AprilGridSpec::default());
    let scene = grid.scene().unwrap();
    let target = Target::AprilGrid(grid.spec);
    let rays = [RayTable::new(&left).unwrap(), RayTable::new(&right).unwrap()];
    let (mut dl, mut dr) = (vec![], vec![]);
    let mut k = 0;
    for alpha in [-20.0, 0.0, 20.0] {
        for gamma in [-25.0, 0.0, 25.0] {
            // the head turns; both cameras move with it
            let head = Pose::new(Fick::from_deg([alpha, 0.15 * gamma, gamma]).to_matrix(), Vector3::zeros());
            for (side, pose) in [(0, head), (1, head.compose(&right_in_left))] {
                let opts =
                    RenderOptions { supersample: 2, blur_sigma: 0.6, noise_sigma: 1.0, seed: k, ..Default::default() };
                k += 1;
                let img = abvs_render::render_with_rays(&scene, &rays[side], &to_iso_m(&pose), &opts).unwrap();
                let g = gray_mat(img.width, img.height, &img.gray).unwrap();
                let d = detect(&g, &target, AprilDetector::AprilGridCrate).unwrap();
                if side == 0 { &mut dl } else { &mut dr }.push((!d.corners.is_empty()).then_some(d));
            }
        }
    }
    let r = calibrate_stereo(&dl, &dr, &target, Model::Fisheye, 12, &CalibOptions::default()).unwrap();
    let rot = Matrix3::from_fn(|i, j| r.rotation[i][j]);
    let t = Vector3::from(r.translation_mm);
    let rot_err = rotation_angle_deg(&rot, &r_true);
    let t_err = (t - t_true).norm();
    eprintln!(
        "{} pairs used; RMS left {:.3} right {:.3} stereo {:.3} px; T {t:?} (error {t_err:.3} mm), R error {rot_err:.4} deg",
        r.pairs_used, r.left.rms_px, r.right.rms_px, r.rms_px
    );
    for (name, got, truth) in [("left", &r.left.camera, &left), ("right", &r.right.camera, &right)] {
        eprintln!(
            "{name}: fx {:.2} ({:.2}) fy {:.2} ({:.2}) cx {:.2} ({:.2}) cy {:.2} ({:.2}) k {:?}",
            got.fx,
            truth.fx,
            got.fy,
            truth.fy,
            got.cx,
            truth.cx,
            got.cy,
            truth.cy,
            got.distortion.coefficients()
        );
        assert!((got.fx / truth.fx - 1.0).abs() < 0.003 && (got.fy / truth.fy - 1.0).abs() < 0.003, "{name} focal");
        assert!((got.cx - truth.cx).abs() < 1.5 && (got.cy - truth.cy).abs() < 1.5, "{name} principal point");
        // the lens maps rays the same way over the field: compare projections of rays up to 55 deg
        let mut worst: f64 = 0.0;
        for deg in [10.0f64, 25.0, 40.0, 55.0] {
            for az in [0.0f64, 90.0, 200.0] {
                let (th, ph) = (deg.to_radians(), az.to_radians());
                let ray = Vector3::new(th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos());
                let (a, b) = (got.project(&ray).unwrap(), truth.project(&ray).unwrap());
                worst = worst.max((a - b).norm());
            }
        }
        eprintln!("{name}: projection difference up to 55 deg: {worst:.3} px");
        assert!(worst < 0.5, "{name}: projections differ by {worst} px");
    }
    assert!(r.rms_px < 0.1, "stereo RMS {} px", r.rms_px);
    assert!(t_err < 0.2, "T error {t_err} mm"); // 0.26 mm before the saddle refinement, 0.062 after
    assert!(rot_err < 0.02, "R error {rot_err} deg");
}
