//! `abvs calib intrinsics | measure | stereo` and `abvs sim aprilgrid-session`: calibration
//! from images, thin shells over abvs-camcal.
use abvs_camcal::detect::{detect_files, AprilDetector, Detection};
use abvs_camcal::intrinsics::{calibrate, views, CalibOptions, Model};
use abvs_camcal::measure::SolveOptions;
use abvs_camcal::render_grid::{write_sim_session, SimSessionSpec};
use abvs_camcal::session::{measure_session, read_stereo_session, Session};
use abvs_camcal::stereo::calibrate_stereo;
use abvs_camcal::target::Target;
use abvs_camera::{CalibInfo, Camera, StereoCalibration};
use abvs_eye::sim::{Commanded, SimSpec};
use abvs_eye::UnitModel;
use anyhow::{bail, Context};
use clap::Args;
use nalgebra::{Matrix3, Vector3};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Args)]
pub struct IntrinsicsArgs {
    /// Images: a glob pattern (quote it), e.g. 'calib/left*.png'.
    #[arg(long)]
    images: String,
    /// aprilgrid[:COLSxROWS:TAG_MM:SPACING] or chessboard:COLSxROWS:SQUARE_MM.
    #[arg(long, default_value = "aprilgrid")]
    target: String,
    /// Lens model to fit.
    #[arg(long, value_enum, default_value_t = Model::Fisheye)]
    model: Model,
    /// Camera calibration to write (OpenCV YAML).
    #[arg(long)]
    out: PathBuf,
    /// AprilGrid detector: aprilgrid (the aprilgrid crate) or opencv (aruco).
    #[arg(long, value_enum, default_value_t = AprilDetector::AprilGridCrate)]
    detector: AprilDetector,
    /// Fewest corners of one board in one image for it to be used (4 to 10000).
    #[arg(long, default_value_t = 12, value_parser = crate::args::count(4usize, 10_000))]
    min_corners: usize,
    /// Images whose RMS error exceeds this many times the median (and 0.3 px) are dropped (1 to 100).
    #[arg(long, default_value_t = 3.0, value_parser = crate::args::finite_in(1.0, 100.0))]
    outlier_factor: f64,
}

fn expand(pattern: &str) -> anyhow::Result<Vec<PathBuf>> {
    let mut v: Vec<PathBuf> =
        glob::glob(pattern).with_context(|| format!("bad pattern '{pattern}'"))?.filter_map(|p| p.ok()).collect();
    v.sort();
    if v.is_empty() {
        bail!("no file matches '{pattern}'");
    }
    Ok(v)
}

fn detect_all(files: &[PathBuf], target: &Target, det: AprilDetector) -> Vec<Option<Detection>> {
    let pb = crate::progress_bar(files.len() as u64, "detecting");
    let out = detect_files(files, target, det, &|| pb.inc(1))
        .into_iter()
        .zip(files)
        .map(|(r, f)| match r {
            Ok(d) if !d.corners.is_empty() => Some(d),
            Ok(_) => {
                eprintln!("{}: no board found", f.display());
                None
            }
            Err(e) => {
                eprintln!("{e}");
                None
            }
        })
        .collect();
    pb.finish_and_clear();
    out
}

fn name(p: &Path) -> String {
    p.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default()
}

pub fn intrinsics(a: IntrinsicsArgs) -> anyhow::Result<ExitCode> {
    let target: Target = a.target.parse()?;
    let model = a.model;
    let files = expand(&a.images)?;
    let dets = detect_all(&files, &target, a.detector);
    let Some((w, h)) = dets.iter().flatten().map(|d| (d.width, d.height)).next() else {
        bail!("no board found in any of {} images", files.len());
    };
    let opts = CalibOptions { outlier_factor: a.outlier_factor, ..Default::default() };
    let c = calibrate(&views(&dets, &target, a.min_corners), w, h, model, &opts)?;
    let info = CalibInfo {
        rms_px: Some(c.rms_px),
        image_names: c.per_image.iter().map(|p| name(&files[p.0])).collect(),
        per_image_errors: c.per_image.iter().map(|p| p.1).collect(),
        rejected_images: c.dropped.iter().map(|p| name(&files[p.0])).collect(),
    };
    c.camera.write_yaml(&a.out, &info)?;
    println!(
        "{} images ({} with a board), {} used, RMS {:.4} px; fx {:.3} fy {:.3} cx {:.3} cy {:.3} {} {:?}",
        files.len(),
        dets.iter().flatten().count(),
        c.per_image.len(),
        c.rms_px,
        c.camera.fx,
        c.camera.fy,
        c.camera.cx,
        c.camera.cy,
        model.name(),
        c.camera.distortion.coefficients()
    );
    for (i, e) in &c.dropped {
        println!("dropped {} (RMS {e:.3} px, far above the median)", files[*i].display());
    }
    println!("wrote {}", a.out.display());
    Ok(ExitCode::SUCCESS)
}

#[derive(Args)]
pub struct MeasureArgs {
    /// Session directory (camcal/README.md): session.toml, index.csv, images.
    #[arg(long)]
    session: PathBuf,
    /// Dataset file to write (dataset.md).
    #[arg(long)]
    out: PathBuf,
    /// AprilGrid detector: aprilgrid (the aprilgrid crate) or opencv (aruco).
    #[arg(long, value_enum, default_value_t = AprilDetector::AprilGridCrate)]
    detector: AprilDetector,
    /// Fewest corners (all boards) for an image to be measured (4 to 10000).
    #[arg(long, default_value_t = 20, value_parser = crate::args::count(4usize, 10_000))]
    min_corners: usize,
    /// Also write the per-image report (JSON).
    #[arg(long)]
    report: Option<PathBuf>,
}

pub fn measure(a: MeasureArgs) -> anyhow::Result<ExitCode> {
    let s = Session::read(&a.session)?;
    let opts = SolveOptions { min_corners: a.min_corners, ..Default::default() };
    let pb = crate::progress_bar(s.rows.len() as u64, "detecting");
    let (ds, rep, solved) = measure_session(&s, a.detector, &opts, |k, _| pb.set_position(k as u64))?;
    pb.finish_and_clear();
    ds.write(&a.out)?;
    let c = rep.failure_counts();
    println!(
        "{} images ({} at home), {} measured; failed: {} unreadable, {} no board, {} too few corners, {} no pose; \
         boards {:?}; RMS {:.4} px over all corners",
        rep.images, rep.home_images, rep.measured, c[0], c[1], c[2], c[3], rep.boards, rep.rms_px
    );
    for (seq, img, f) in &rep.failures {
        println!("  seq {seq} {img}: {f}");
    }
    if let Some(p) = &a.report {
        let j = serde_json::json!({
            "images": rep.images,
            "measured": rep.measured,
            "home_images": rep.home_images,
            "rms_px": rep.rms_px,
            "boards": solved.boards.iter().map(|(b, p)| serde_json::json!({"board": b, "pose": p.to_p6()})).collect::<Vec<_>>(),
            "failures": rep.failures.iter().map(|(s, i, f)| serde_json::json!({"seq": s, "image": i, "why": f.to_string()})).collect::<Vec<_>>(),
            "per_image": rep.per_image.iter().map(|(s, r, n)| serde_json::json!({"seq": s, "rms_px": r, "corners": n})).collect::<Vec<_>>(),
        });
        std::fs::write(p, serde_json::to_string_pretty(&j)?)?;
    }
    println!("wrote {}", a.out.display());
    Ok(if rep.measured > 0 { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}

#[derive(Args)]
pub struct StereoArgs {
    /// Stereo session directory (camcal/README.md): stereo.toml, pairs.csv, images.
    #[arg(long)]
    session: PathBuf,
    /// Stereo calibration to write (OpenCV YAML: both intrinsics and T_lH^rH).
    #[arg(long)]
    out: PathBuf,
    /// AprilGrid detector: aprilgrid (the aprilgrid crate) or opencv (aruco).
    #[arg(long, value_enum, default_value_t = AprilDetector::AprilGridCrate)]
    detector: AprilDetector,
    /// Fewest corners of one board in one image for it to be used (4 to 10000).
    #[arg(long, default_value_t = 12, value_parser = crate::args::count(4usize, 10_000))]
    min_corners: usize,
}

pub fn stereo(a: StereoArgs) -> anyhow::Result<ExitCode> {
    let (meta, pairs) = read_stereo_session(&a.session)?;
    let target: Target = meta.target.parse()?;
    let model: Model = meta.model.parse()?;
    let det = a.detector;
    let left: Vec<PathBuf> = pairs.iter().map(|p| p.0.clone()).collect();
    let right: Vec<PathBuf> = pairs.iter().map(|p| p.1.clone()).collect();
    let (dl, dr) = (detect_all(&left, &target, det), detect_all(&right, &target, det));
    let r = calibrate_stereo(&dl, &dr, &target, model, a.min_corners, &CalibOptions::default())?;
    let sc = StereoCalibration {
        left: r.left.camera,
        right: r.right.camera,
        rotation: Matrix3::from_fn(|i, j| r.rotation[i][j]),
        translation_mm: Vector3::from(r.translation_mm),
        rms_px: Some(r.rms_px),
    };
    sc.write_yaml(&a.out)?;
    println!(
        "{} pairs, {} used; RMS left {:.4} right {:.4} stereo {:.4} px; baseline {:.3} mm; T = {:?} mm",
        pairs.len(),
        r.pairs_used,
        r.left.rms_px,
        r.right.rms_px,
        r.rms_px,
        sc.baseline_mm(),
        r.translation_mm
    );
    for (side, c, files) in [("left", &r.left, &left), ("right", &r.right, &right)] {
        for (i, e) in &c.dropped {
            println!("dropped {side} {} (RMS {e:.3} px)", files[*i].display());
        }
    }
    println!("wrote {}", a.out.display());
    Ok(ExitCode::SUCCESS)
}

#[derive(Args)]
pub struct SimSessionArgs {
    /// Session directory to write (session.toml, index.csv, images, truth.csv, camera.yaml).
    #[arg(long)]
    out: PathBuf,
    /// Unit model (TOML); default: a unit drawn with --seed, all kinematic effects, no measurement noise.
    #[arg(long)]
    unit: Option<PathBuf>,
    /// Seed of the drawn unit and of the image noise.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// n values per axis of the commanded grid (n^3 poses; 2 to 20) ...
    #[arg(long, default_value_t = 3, value_parser = crate::args::count(2usize, 20))]
    grid_n: usize,
    /// ... or this many random poses of the 3 deg grid (1 to 10000).
    #[arg(long, value_parser = crate::args::count(1usize, 10_000))]
    random: Option<usize>,
    /// Home images at the start (0 to 100).
    #[arg(long, default_value_t = 2, value_parser = crate::args::count(0usize, 100))]
    home: usize,
    /// Image noise sigma (grey levels, 0 to 100).
    #[arg(long, default_value_t = 1.0, value_parser = crate::args::finite_in(0.0, 100.0))]
    noise: f64,
    /// Blur sigma (px, 0 to 10).
    #[arg(long, default_value_t = 0.6, value_parser = crate::args::finite_in(0.0, 10.0))]
    blur: f64,
    /// Supersampling (n x n samples per pixel, 1 to 8).
    #[arg(long, default_value_t = 4, value_parser = crate::args::count(1u32, 8))]
    supersample: u32,
    /// Every n-th image is replaced by an unreadable file (0: none), to exercise failure handling.
    #[arg(long, default_value_t = 0, value_parser = crate::args::count(0usize, 1_000_000))]
    corrupt_every: usize,
}

pub fn sim_session(a: SimSessionArgs) -> anyhow::Result<ExitCode> {
    let unit = match &a.unit {
        Some(p) => UnitModel::load(p)?,
        None => abvs_camcal::render_grid::default_unit(a.seed),
    };
    let sim = SimSpec {
        commanded: if a.random.is_some() { Commanded::Step(3.0) } else { Commanded::PerAxis(a.grid_n) },
        random: a.random,
        seed: a.seed,
        dropout: 0.0,
        ..Default::default()
    };
    let spec = SimSessionSpec {
        sim,
        camera: Camera::ov8856(),
        home_images: a.home,
        noise_sigma: a.noise,
        blur_sigma: a.blur,
        supersample: a.supersample,
        corrupt_every: a.corrupt_every,
        ..Default::default()
    };
    let pb = crate::progress_bar(0, "rendering");
    let truth = write_sim_session(&a.out, &unit, &spec, crate::progress_to(&pb))?;
    pb.finish_and_clear();
    println!("wrote {} ({} images + {} home; truth.csv, camera.yaml)", a.out.display(), truth.len() - a.home, a.home);
    Ok(ExitCode::SUCCESS)
}

#[derive(Args)]
pub struct SimStereoArgs {
    /// The pair to render (OpenCV YAML of `abvs calib stereo`: both intrinsics and T_lH^rH).
    #[arg(long)]
    truth: PathBuf,
    /// Session directory to write (stereo.toml, pairs.csv, images).
    #[arg(long)]
    out: PathBuf,
    /// n x n head orientations (alpha, gamma over +-range) at each distance.
    #[arg(long, default_value_t = 5, value_parser = crate::args::count(2usize, 20))]
    n: usize,
    /// Half-range of the head orientations (deg, up to 60).
    #[arg(long, default_value_t = 25.0, value_parser = crate::args::positive_up_to(60.0))]
    range_deg: f64,
    /// Distances from the boards (mm, comma-separated, each >= 200): at one alone, a camera slightly forward
    /// and one with a slightly longer lens look alike (the fixture's T was 0.6 mm off along the axis).
    #[arg(long, value_delimiter = ',', default_value = "600,1000,1500", value_parser = crate::args::finite_in(200.0, 1e5))]
    distances_mm: Vec<f64>,
    /// Seed of the image noise.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Image noise sigma (grey levels, 0 to 100).
    #[arg(long, default_value_t = 1.0, value_parser = crate::args::finite_in(0.0, 100.0))]
    noise: f64,
    /// Blur sigma (px, 0 to 10).
    #[arg(long, default_value_t = 0.6, value_parser = crate::args::finite_in(0.0, 10.0))]
    blur: f64,
    /// Supersampling (n x n samples per pixel, 1 to 8).
    #[arg(long, default_value_t = 2, value_parser = crate::args::count(1u32, 8))]
    supersample: u32,
}

/// `abvs sim stereo-session`: a stereo calibration session at home rendered for a known pair.
pub fn sim_stereo(a: SimStereoArgs) -> anyhow::Result<ExitCode> {
    use abvs_camcal::render_grid::{write_stereo_sim_session, StereoSessionSpec};
    let truth = StereoCalibration::read_yaml(&a.truth)?;
    let spec = StereoSessionSpec {
        n: a.n,
        half_range_deg: a.range_deg,
        distances_mm: a.distances_mm,
        noise_sigma: a.noise,
        blur_sigma: a.blur,
        supersample: a.supersample,
        seed: a.seed,
        ..Default::default()
    };
    let pb = crate::progress_bar(0, "rendering");
    let n = write_stereo_sim_session(&a.out, &truth, &spec, crate::progress_to(&pb))?;
    pb.finish_and_clear();
    println!("wrote {} ({n} pairs; stereo.toml, pairs.csv, truth.yaml)", a.out.display());
    Ok(ExitCode::SUCCESS)
}
