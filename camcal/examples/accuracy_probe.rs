//! Where does the pose error of the rendered session come from? Solves the same 12-image session
//! (a) from the true corners + Gaussian noise, (b) from detected corners, and prints translation /
//! rotation RMS vs truth and the corner error statistics. `cargo run --release -p abvs-camcal --example accuracy_probe [supersample]`
use abvs_camcal::detect::{detect, gray_mat, AprilDetector, Corner, Detection};
use abvs_camcal::measure::{solve, SolveOptions};
use abvs_camcal::render_grid::{default_unit, to_iso_m, GridScene};
use abvs_camcal::target::{AprilGridSpec, Target};
use abvs_camera::Camera;
use abvs_eye::pose::rotation_angle_deg;
use abvs_eye::sim::{simulate_dataset, Commanded, SimSpec};
use abvs_eye::Pose;
use abvs_render::RenderOptions;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

fn main() {
    let ss: u32 = std::env::args().nth(1).map(|s| s.parse().unwrap()).unwrap_or(4);
    let blur: f64 = std::env::args().nth(2).map(|s| s.parse().unwrap()).unwrap_or(0.6);
    let cam = Camera::ov8856();
    let grid = GridScene::paper(AprilGridSpec::default());
    let scene = grid.scene().unwrap();
    let target = Target::AprilGrid(grid.spec);
    let unit = default_unit(5);
    let spec = SimSpec { commanded: Commanded::PerAxis(2), dropout: 0.0, seed: 3, ..Default::default() };
    let (sim, _) = simulate_dataset(&unit, &spec, |_, _| {}).unwrap();
    let mut poses: Vec<Pose> = vec![Pose::identity(); 4];
    poses.extend(sim.samples.iter().map(|s| Pose::from_p6(&s.pose)));
    let home: Vec<bool> = (0..poses.len()).map(|i| i < 4).collect();
    let truth_dets: Vec<Detection> = poses
        .iter()
        .map(|p| Detection {
            width: 1600,
            height: 1200,
            corners: grid.true_corners(&cam, p).into_iter().map(|(id, px)| Corner { id, px }).collect(),
        })
        .collect();
    let report = |name: &str, dets: &[Detection]| {
        let d: Vec<_> = dets.iter().cloned().map(Ok).collect();
        let s = solve(&cam, &target, &d, &home, &SolveOptions::default()).unwrap();
        let (mut sr, mut st, mut n) = (0.0, 0.0, 0);
        for i in 4..poses.len() {
            let p = s.poses[i].as_ref().unwrap();
            sr += rotation_angle_deg(&p.r, &poses[i].r).powi(2);
            st += (p.t - poses[i].t).norm_squared();
            n += 1;
        }
        println!(
            "{name}: rotation RMS {:.5} deg, translation RMS {:.4} mm, reprojection RMS {:.4} px",
            (sr / n as f64).sqrt(),
            (st / n as f64).sqrt(),
            s.rms_px
        );
    };
    report("true corners", &truth_dets);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    for sigma in [0.02, 0.039] {
        let nd = Normal::new(0.0, sigma).unwrap();
        let noisy: Vec<Detection> = truth_dets
            .iter()
            .map(|d| Detection {
                corners: d
                    .corners
                    .iter()
                    .map(|c| Corner { id: c.id, px: [c.px[0] + nd.sample(&mut rng), c.px[1] + nd.sample(&mut rng)] })
                    .collect(),
                ..d.clone()
            })
            .collect();
        report(&format!("true + N(0, {sigma})"), &noisy);
    }
    let rays = abvs_render::RayTable::new(&cam).unwrap();
    let mut dets = vec![];
    let (mut e2, mut en, mut ex, mut ey) = (0.0, 0usize, 0.0, 0.0);
    for (k, p) in poses.iter().enumerate() {
        let opts =
            RenderOptions { supersample: ss, blur_sigma: blur, noise_sigma: 1.0, seed: k as u64, ..Default::default() };
        let img = abvs_render::render_with_rays(&scene, &rays, &to_iso_m(p), &opts).unwrap();
        let g = gray_mat(img.width, img.height, &img.gray).unwrap();
        let d = detect(&g, &target, AprilDetector::AprilGridCrate).unwrap();
        for c in &d.corners {
            if let Some(t) = truth_dets[k].corners.iter().find(|t| t.id == c.id) {
                let (dx, dy) = (c.px[0] - t.px[0], c.px[1] - t.px[1]);
                e2 += dx * dx + dy * dy;
                ex += dx;
                ey += dy;
                en += 1;
            }
        }
        dets.push(d);
    }
    println!(
        "detected (supersample {ss}, blur {blur}): {en} corners, error RMS {:.4} px, mean ({:.4}, {:.4}) px",
        (e2 / en as f64).sqrt(),
        ex / en as f64,
        ey / en as f64
    );
    report("detected", &dets);
}
