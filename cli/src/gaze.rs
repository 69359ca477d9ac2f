//! `abvs gaze`: pointing both eyes. `fixate` solves both eyes' calibrated IK so that a 3D point
//! lies on each camera's principal point (abvs_calib::gaze); `saccade` drives the drive board
//! there over its serial link (crate::saccade).
use abvs_calib::gaze::{optical_axis, EyeAim, Fixation, Torsion};
use abvs_camera::Camera;
use abvs_runtime::gaze::direct::{pixel, HeadCalibration};
use anyhow::Context;
use clap::{Args, Subcommand};
use nalgebra::Vector2;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Subcommand)]
pub enum GazeCmd {
    /// Both eyes' link angles and counts that fixate a 3D point (left home camera frame, metres).
    Fixate(FixateArgs),
    /// Drive the board: home from its stream, then minimum-jerk saccades to targets (command frames).
    Saccade(crate::saccade::SaccadeArgs),
}

#[derive(Args)]
pub struct FixateArgs {
    /// Calibration directory: stereo.yaml (intrinsics, T_lH^rH) and eye0, eye1 (FK models).
    #[arg(long)]
    calib: PathBuf,
    /// x,y,z in metres, in the left home camera frame (x right, y down, z forward; each within +-100 m).
    #[arg(long, value_parser = crate::args::point_m, allow_hyphen_values = true, required_unless_present = "pixel", conflicts_with = "pixel")]
    point: Option<[f64; 3]>,
    /// Instead of --point: a pixel u,v of the current left image (raw, as the camera delivers it;
    /// its intrinsics and distortion from stereo.yaml) ...
    #[arg(long, value_parser = crate::args::pixel, allow_hyphen_values = true, requires = "depth")]
    pixel: Option<[f64; 2]>,
    /// ... its depth in metres (z in the left camera frame, the depth map's convention; up to 100) ...
    #[arg(long, allow_hyphen_values = true, value_parser = crate::args::positive_up_to(100.0))]
    depth: Option<f64>,
    /// ... and the left eye's link angles when the image was taken (deg, each within +-89; default home).
    #[arg(long, value_parser = crate::args::link_angles, allow_hyphen_values = true, default_value = "0,0,0")]
    left_theta: [f64; 3],
    /// Torsion about the line of sight: listing (Listing's law) or zero-fick (Fick roll 0).
    #[arg(long, value_enum, default_value_t = Torsion::Listing)]
    torsion: Torsion,
    /// Gravity in both eyes' base frames (unit vector; default: head upright).
    #[arg(long, value_parser = crate::args::gravity, allow_hyphen_values = true, default_value = "0,1,0")]
    gravity: [f64; 3],
    /// Print JSON instead of the table.
    #[arg(long)]
    json: bool,
}

pub fn run(cmd: GazeCmd) -> anyhow::Result<ExitCode> {
    match cmd {
        GazeCmd::Fixate(a) => fixate(a),
        GazeCmd::Saccade(a) => crate::saccade::saccade(a),
    }
}

fn fixate(a: FixateArgs) -> anyhow::Result<ExitCode> {
    let torsion = a.torsion;
    let head = HeadCalibration::load(&a.calib)?;
    let (stereo, [ml, mr]) = (&head.stereo, &head.models);
    let bino = head.binocular(torsion);
    let point_mm = match (a.point, a.pixel, a.depth) {
        (Some(p), _, _) => p.map(|v| v * 1000.0),
        (None, Some(px), Some(depth)) => {
            let ray = stereo
                .left
                .unproject(&Vector2::new(px[0], px[1]))
                .with_context(|| format!("pixel {px:?}: outside the left camera model's valid field"))?;
            abvs_calib::gaze::point_from_view(ml, a.left_theta, a.gravity, &ray, depth * 1000.0)?
        }
        _ => anyhow::bail!("give --point, or --pixel with --depth"),
    };
    let f: Fixation = bino.fixate_from_home(point_mm, a.gravity)?;
    let eyes = [("left (eye0)", &f.left, &stereo.left), ("right (eye1)", &f.right, &stereo.right)];
    if a.json {
        let eye = |aim: &EyeAim, cam: &Camera| {
            serde_json::json!({
                "target_deg": aim.ik.target_deg,
                "theta_deg": aim.ik.theta_deg,
                "counts": aim.ik.counts(),
                "pose": aim.ik.pose,
                "residual_deg": aim.ik.residual_deg,
                "point_mm": aim.point_mm,
                "range_mm": aim.range_mm,
                "predicted_miss_mm": aim.predicted_miss_mm,
                "pixel": pixel(cam, aim).map(|p| [p.x, p.y]),
                "principal_point": [cam.cx, cam.cy],
            })
        };
        let v = serde_json::json!({
            "point_m": point_mm.map(|v| v / 1000.0),
            "torsion": torsion.name(),
            "vergence_deg": f.vergence_deg,
            "left": eye(&f.left, &stereo.left),
            "right": eye(&f.right, &stereo.right),
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(ExitCode::SUCCESS);
    }
    println!(
        "fixating [{:.3}, {:.3}, {:.3}] m (left home camera frame), torsion {}, models {} / {}",
        point_mm[0] / 1000.0,
        point_mm[1] / 1000.0,
        point_mm[2] / 1000.0,
        torsion.name(),
        ml.method(),
        mr.method()
    );
    println!("| eye | orientation alpha, beta, gamma (deg) | theta1..3 (deg) | counts | optical centre (mm) | range (mm) | point's pixel / principal point |");
    println!("| --- | --- | --- | --- | --- | --- | --- |");
    for (name, aim, cam) in eyes {
        let t = &aim.ik.target_deg;
        let th = &aim.ik.theta_deg;
        let c = aim.ik.counts();
        let centre = optical_axis(&aim.ik.pose).0;
        let px = pixel(cam, aim).map(|p| format!("{:.3}, {:.3}", p.x, p.y)).unwrap_or_else(|| "-".into());
        println!(
            "| {name} | {:.4}, {:.4}, {:.4} | {:.4}, {:.4}, {:.4} | {}, {}, {} | {:.3}, {:.3}, {:.3} | {:.1} | {px} / {:.3}, {:.3} |",
            t[0], t[1], t[2], th[0], th[1], th[2], c[0], c[1], c[2], centre.x, centre.y, centre.z, aim.range_mm, cam.cx, cam.cy
        );
    }
    println!(
        "vergence {:.4} deg; IK residual {:.1e} / {:.1e} deg; predicted miss {:.1e} / {:.1e} mm",
        f.vergence_deg,
        f.left.ik.residual_deg,
        f.right.ik.residual_deg,
        f.left.predicted_miss_mm,
        f.right.predicted_miss_mm
    );
    Ok(ExitCode::SUCCESS)
}
