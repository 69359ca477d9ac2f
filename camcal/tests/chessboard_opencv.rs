//! Intrinsics and stereo on the real chessboard stereo set of opencv-doc (left01..14 and
//! right01..14 without 10, 640x480, 9x6 inner corners; square size taken as 25 mm), compared
//! with OpenCV's own calibration of the same images (cv::calibrateCamera per camera, then
//! cv::stereoCalibrate with the intrinsics fixed), called directly here as the reference.
use abvs_camcal::detect::{detect, load_gray, AprilDetector, Detection};
use abvs_camcal::intrinsics::{calibrate, views, CalibOptions, Model};
use abvs_camcal::stereo::calibrate_stereo;
use abvs_camcal::target::{ChessboardSpec, Target};
use opencv::core::{Mat, Point2f, Point3f, Size, TermCriteria, TermCriteria_Type, Vector, CV_64F};
use opencv::prelude::*;
use opencv::{calib3d, imgproc};
use std::path::PathBuf;

const DATA: &str = "/usr/share/doc/opencv-doc/examples/data";
const SQUARE_MM: f64 = 25.0;

fn files(side: &str) -> Vec<PathBuf> {
    [1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 14]
        .iter()
        .map(|i| PathBuf::from(format!("{DATA}/{side}{i:02}.jpg")))
        .collect()
}

fn target() -> Target {
    Target::Chessboard(ChessboardSpec { cols: 9, rows: 6, square_mm: SQUARE_MM })
}

fn ours(side: &str) -> Vec<Option<Detection>> {
    files(side)
        .iter()
        .map(|f| {
            let g = load_gray(f).expect("opencv-doc image (scripts/setup.sh installs opencv-doc)");
            let d = detect(&g, &target(), AprilDetector::OpenCv).unwrap();
            (!d.corners.is_empty()).then_some(d)
        })
        .collect()
}

/// The reference: OpenCV calibration straight from findChessboardCorners + cornerSubPix.
struct Reference {
    k: [Mat; 2],
    d: [Mat; 2],
    r: Mat,
    t: Mat,
    rms: [f64; 3],
}

fn reference(keep: &[usize]) -> Reference {
    let crit =
        TermCriteria::new((TermCriteria_Type::COUNT as i32) | (TermCriteria_Type::EPS as i32), 30, 0.01).unwrap();
    let mut pts: [Vector<Vector<Point2f>>; 2] = [Vector::new(), Vector::new()];
    let mut obj: Vector<Vector<Point3f>> = Vector::new();
    for (i, (l, r)) in files("left").iter().zip(files("right")).enumerate() {
        if !keep.contains(&i) {
            continue;
        }
        let mut pair = Vec::new();
        for f in [l, &r] {
            let g = opencv::imgcodecs::imread(f.to_str().unwrap(), opencv::imgcodecs::IMREAD_GRAYSCALE).unwrap();
            let mut c: Vector<Point2f> = Vector::new();
            let ok = calib3d::find_chessboard_corners(
                &g,
                Size::new(9, 6),
                &mut c,
                calib3d::CALIB_CB_ADAPTIVE_THRESH | calib3d::CALIB_CB_NORMALIZE_IMAGE,
            )
            .unwrap();
            if ok {
                imgproc::corner_sub_pix(&g, &mut c, Size::new(11, 11), Size::new(-1, -1), crit).unwrap();
                pair.push(c);
            }
        }
        if pair.len() == 2 {
            pts[0].push(pair[0].clone());
            pts[1].push(pair[1].clone());
            let mut o = Vector::new();
            for j in 0..6 {
                for i in 0..9 {
                    o.push(Point3f::new((i as f64 * SQUARE_MM) as f32, (j as f64 * SQUARE_MM) as f32, 0.0));
                }
            }
            obj.push(o);
        }
    }
    assert!(obj.len() >= 8, "reference found the board in {} pairs", obj.len());
    let size = Size::new(640, 480);
    let crit =
        TermCriteria::new((TermCriteria_Type::COUNT as i32) | (TermCriteria_Type::EPS as i32), 100, 1e-10).unwrap();
    let mut ks = Vec::new();
    let mut ds = Vec::new();
    let mut rms = [0.0; 3];
    for s in 0..2 {
        let mut k = Mat::eye(3, 3, CV_64F).unwrap().to_mat().unwrap();
        let mut d = Mat::zeros(5, 1, CV_64F).unwrap().to_mat().unwrap();
        let (mut rv, mut tv) = (Vector::<Mat>::new(), Vector::<Mat>::new());
        rms[s] = calib3d::calibrate_camera(&obj, &pts[s], size, &mut k, &mut d, &mut rv, &mut tv, 0, crit).unwrap();
        ks.push(k);
        ds.push(d);
    }
    let (mut r, mut t, mut e, mut f) = (Mat::default(), Mat::default(), Mat::default(), Mat::default());
    let (mut k0, mut d0, mut k1, mut d1) = (ks[0].clone(), ds[0].clone(), ks[1].clone(), ds[1].clone());
    rms[2] = calib3d::stereo_calibrate(
        &obj,
        &pts[0],
        &pts[1],
        &mut k0,
        &mut d0,
        &mut k1,
        &mut d1,
        size,
        &mut r,
        &mut t,
        &mut e,
        &mut f,
        calib3d::CALIB_FIX_INTRINSIC,
        crit,
    )
    .unwrap();
    Reference { k: [k0, k1], d: [d0, d1], r, t, rms }
}

fn at(m: &Mat, r: i32, c: i32) -> f64 {
    *m.at_2d::<f64>(r, c).unwrap()
}

/// Compares our stereo calibration with OpenCV's on the image pairs we kept; tolerances:
/// focal lengths `f_rel`, principal point `c_px`, rotation `r_deg`, translation `t_rel`.
fn check(opts: &CalibOptions, f_rel: f64, c_px: f64, r_deg: f64, t_rel: f64) {
    let (l, r) = (ours("left"), ours("right"));
    assert!(l.iter().flatten().count() >= 12 && r.iter().flatten().count() >= 12);
    let res = calibrate_stereo(&l, &r, &target(), Model::Pinhole, 20, opts).unwrap();
    let keep: Vec<usize> =
        res.left.per_image.iter().map(|p| p.0).filter(|i| res.right.per_image.iter().any(|q| q.0 == *i)).collect();
    let rf = reference(&keep);
    eprintln!(
        "ours: left rms {:.4} px ({} images, dropped {:?}), right rms {:.4} px (dropped {:?}), stereo rms {:.4} px over {} pairs",
        res.left.rms_px,
        res.left.per_image.len(),
        res.left.dropped,
        res.right.rms_px,
        res.right.dropped,
        res.rms_px,
        res.pairs_used
    );
    eprintln!(
        "opencv on the same {} pairs: rms left {:.4} right {:.4} stereo {:.4}",
        keep.len(),
        rf.rms[0],
        rf.rms[1],
        rf.rms[2]
    );
    assert!(res.left.rms_px < 0.5 && res.right.rms_px < 0.5 && res.rms_px < 0.5);
    for (side, c) in [(0usize, &res.left), (1, &res.right)] {
        let i = &c.camera;
        let k = &rf.k[side];
        eprintln!(
            "side {side}: fx {:.3} vs {:.3}, fy {:.3} vs {:.3}, cx {:.3} vs {:.3}, cy {:.3} vs {:.3}, k1 {:.4} vs {:.4}",
            i.fx,
            at(k, 0, 0),
            i.fy,
            at(k, 1, 1),
            i.cx,
            at(k, 0, 2),
            i.cy,
            at(k, 1, 2),
            i.distortion.coefficients()[0],
            at(&rf.d[side].reshape(1, 1).unwrap().try_clone().unwrap(), 0, 0)
        );
        assert!((i.fx / at(k, 0, 0) - 1.0).abs() < f_rel, "fx");
        assert!((i.fy / at(k, 1, 1) - 1.0).abs() < f_rel, "fy");
        assert!((i.cx - at(k, 0, 2)).abs() < c_px, "cx");
        assert!((i.cy - at(k, 1, 2)).abs() < c_px, "cy");
    }
    let rr = nalgebra::Matrix3::from_fn(|i, j| res.rotation[i][j]);
    let rref = nalgebra::Matrix3::from_fn(|i, j| at(&rf.r, i as i32, j as i32));
    let ang = abvs_eye::pose::rotation_angle_deg(&rr, &rref);
    let tref = rf.t.reshape(1, 3).unwrap().try_clone().unwrap();
    let tr = nalgebra::Vector3::new(at(&tref, 0, 0), at(&tref, 1, 0), at(&tref, 2, 0));
    let t = nalgebra::Vector3::from(res.translation_mm);
    eprintln!(
        "R differs by {ang:.4} deg; T ours {:?} mm vs opencv {:?} mm (|dT| {:.3} mm, baseline {:.2} mm)",
        t.as_slice(),
        tr.as_slice(),
        (t - tr).norm(),
        tr.norm()
    );
    assert!(ang < r_deg, "R differs by {ang} deg");
    assert!((t - tr).norm() < t_rel * tr.norm(), "T differs by {} mm", (t - tr).norm());
}

/// Without outlier rejection: the same images as OpenCV, so the same answer.
#[test]
fn stereo_and_intrinsics_match_opencv_on_all_images() {
    let opts = CalibOptions { max_rounds: 0, ..Default::default() };
    check(&opts, 0.001, 0.5, 0.02, 0.002);
}

/// With the default rejection (left02 / right02 have RMS ~1.2 px, 5x the median): OpenCV on the
/// pairs kept by both cameras must agree (looser: each of our intrinsics also uses the images
/// only its own camera kept, 12 left vs the 11 common pairs of the reference).
#[test]
fn stereo_and_intrinsics_match_opencv_after_rejection() {
    check(&CalibOptions::default(), 0.001, 0.5, 0.05, 0.005);
}

#[test]
fn outlier_image_is_dropped_and_reported() {
    let mut l = ours("left");
    // corrupt one image: its corners shifted by a smooth 3-6 px warp (a bad detection)
    let bad = 4;
    if let Some(d) = l[bad].as_mut() {
        for (k, c) in d.corners.iter_mut().enumerate() {
            c.px[0] += 3.0 + 3.0 * ((k as f64) * 0.7).sin();
            c.px[1] -= 3.0 * ((k as f64) * 0.3).cos();
        }
    }
    let v = views(&l, &target(), 20);
    let c = calibrate(&v, 640, 480, Model::Pinhole, &CalibOptions::default()).unwrap();
    eprintln!("dropped {:?}, rms {:.4}", c.dropped, c.rms_px);
    // left02 (index 1) is a natural outlier of this set (RMS ~1.2 px, 5x the median); the
    // corrupted image must be dropped as well, and nothing else
    let clean =
        calibrate(&views(&ours("left"), &target(), 20), 640, 480, Model::Pinhole, &CalibOptions::default()).unwrap();
    let mut expect: Vec<usize> = clean.dropped.iter().map(|d| d.0).chain([bad]).collect();
    expect.sort();
    let mut got: Vec<usize> = c.dropped.iter().map(|d| d.0).collect();
    got.sort();
    assert!(!clean.dropped.iter().any(|d| d.0 == bad));
    assert_eq!(got, expect);
    assert!(c.rms_px < 0.5);
    assert!(!c.per_image.iter().any(|p| p.0 == bad));
}

/// The detection of many files at once (spread over the cores, as `abvs calib` runs it) gives each file what
/// one detection of it alone gives, in the files' order, a missing file's error in its own place, and one
/// progress call per file.
#[test]
fn detecting_files_in_parallel_keeps_each_files_result_in_its_place() {
    let mut f = files("left");
    f.insert(3, PathBuf::from(format!("{DATA}/no_such_image.jpg")));
    let calls = std::sync::atomic::AtomicUsize::new(0);
    let done = || {
        calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    };
    let all = abvs_camcal::detect::detect_files(&f, &target(), AprilDetector::OpenCv, &done);
    assert_eq!((all.len(), calls.into_inner()), (f.len(), f.len()));
    for (i, (got, file)) in all.iter().zip(&f).enumerate() {
        if i == 3 {
            let e = got.as_ref().expect_err("a missing file").to_string();
            assert!(e.contains("no_such_image.jpg"), "{e}");
            continue;
        }
        let one = detect(&load_gray(file).unwrap(), &target(), AprilDetector::OpenCv).unwrap();
        assert_eq!(got.as_ref().unwrap(), &one, "{}", file.display());
        assert!(!one.corners.is_empty(), "{}", file.display());
    }
}
