//! `abvs gaze saccade`: solve the calibrated IK of each target, plan the yoked move, run it on the drive board
//! and measure it on the board's stream (`abvs_runtime::gaze::direct`), print the table.
use abvs_board::saccade::BoardSession;
use abvs_calib::gaze::Torsion;
use abvs_eye::saccade::PEAK_SPEED_DEG_S;
use abvs_runtime::gaze::direct::{self, HeadCalibration, SaccadeTarget};
use anyhow::bail;
use clap::Args;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

#[derive(Args)]
pub struct SaccadeArgs {
    /// The drive board's serial port (a /dev/pts/N for the simulated board).
    #[arg(long)]
    port: String,
    /// Calibration directory: stereo.yaml and eye0, eye1 (FK models).
    #[arg(long)]
    calib: PathBuf,
    /// Targets in order, "alpha,beta,gamma;..." (deg): both eyes to that orientation.
    #[arg(long, allow_hyphen_values = true)]
    orientation: Option<String>,
    /// Targets in order, "x,y,z;..." (m, left home camera frame): both eyes fixate each point.
    #[arg(long, allow_hyphen_values = true)]
    point: Option<String>,
    /// Torsion rule for --point: listing or zero-fick.
    #[arg(long, value_enum, default_value_t = Torsion::Listing)]
    torsion: Torsion,
    /// Peak link speed of the minimum-jerk moves (deg/s, up to 5000).
    #[arg(long, default_value_t = PEAK_SPEED_DEG_S, value_parser = crate::args::positive_up_to(5000.0))]
    peak_deg_s: f64,
    /// Give up waiting for homing or for an arrival after this long (s, up to 1e9).
    #[arg(long, default_value_t = 10.0, value_parser = crate::args::seconds())]
    timeout_s: f64,
    /// Print JSON instead of the table.
    #[arg(long)]
    json: bool,
}

pub fn saccade(a: SaccadeArgs) -> anyhow::Result<ExitCode> {
    let targets = match (&a.orientation, &a.point) {
        (Some(o), None) => crate::parse_list(o)?,
        (None, Some(p)) => crate::parse_list(p)?,
        _ => bail!("give exactly one of --orientation and --point"),
    };
    let head = HeadCalibration::load(&a.calib)?;
    let (models, bino) = (&head.models, head.binocular(a.torsion));
    let mut link = BoardSession::open(&a.port)?;
    let timeout = Duration::from_secs_f64(a.timeout_s);
    let (home, mut st) = direct::start(&mut link, [&models[0], &models[1]], timeout)?;
    eprintln!("homed: home counts {home:?}");
    let mut reports = vec![];
    for target in targets {
        let t = if a.point.is_some() { SaccadeTarget::Point(target) } else { SaccadeTarget::Orientation(target) };
        let rep = direct::saccade(&mut link, &bino, &mut st, home, t, a.peak_deg_s, timeout)?;
        if !a.json {
            println!(
                "saccade to [{:.3}, {:.3}, {:.3}]: link travel {:.2} deg, planned {:.2} ms (minimum jerk, peak {:.0} deg/s); \
                 measured {:.2} / {:.2} ms, peak {:.0} / {:.0} deg/s (left / right){}",
                target[0],
                target[1],
                target[2],
                rep.travel_deg,
                rep.planned_ms,
                a.peak_deg_s,
                rep.measured_ms[0],
                rep.measured_ms[1],
                rep.peak_deg_s[0],
                rep.peak_deg_s[1],
                if rep.arrived { "" } else { "; NOT ARRIVED" }
            );
        }
        reports.push(rep);
    }
    let stats = link.stats();
    eprintln!(
        "encoder stream: {} homed samples consumed (left {}, right {}), {} frames, {} CRC errors, {} lost",
        link.homed_samples(),
        stats.samples[0],
        stats.samples[1],
        stats.link.frames,
        stats.link.crc_errors,
        stats.link.lost_frames
    );
    if a.json {
        let v = serde_json::json!({
            "saccades": reports,
            "encoders": stats,
            "homed_samples": link.homed_samples(),
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
    }
    Ok(if reports.iter().all(|r| r.arrived) { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}
