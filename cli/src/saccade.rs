//! `abvs gaze saccade`: solve the calibrated IK of each target, plan the yoked move (`abvs_fk::gaze`), run
//! it on the drive board and measure it on the board's stream (`abvs_board::saccade`), print the table.
use abvs_board::saccade::BoardSession;
use abvs_calib::gaze::{Binocular, Torsion, YokedSaccade};
use abvs_calib::ik::CalibratedIk;
use abvs_calib::model::{FkModel, FkState};
use abvs_camera::StereoCalibration;
use abvs_eye::pose::Pose;
use abvs_eye::saccade::PEAK_SPEED_DEG_S;
use anyhow::{bail, Context};
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

/// What one saccade did, measured on the encoder stream.
#[derive(Debug)]
struct Report {
    target: [f64; 3],
    /// Per eye: link angles before and after (deg), target counts (homed).
    from_deg: [[f64; 3]; 2],
    to_deg: [[f64; 3]; 2],
    target_counts: [[i64; 3]; 2],
    /// Largest link travel over both eyes (deg).
    travel_deg: f64,
    planned_ms: f64,
    /// From the first moving sample to the first sample at the target (board time), per eye.
    measured_ms: [f64; 2],
    /// Largest link speed between consecutive samples (deg/s), per eye.
    peak_deg_s: [f64; 2],
    arrived: bool,
}

impl Report {
    fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "target": self.target,
            "from_deg": self.from_deg,
            "to_deg": self.to_deg,
            "target_counts": self.target_counts,
            "travel_deg": self.travel_deg,
            "planned_ms": self.planned_ms,
            "measured_ms": self.measured_ms,
            "peak_deg_s": self.peak_deg_s,
            "arrived": self.arrived,
        })
    }
}

fn parse_list(s: &str) -> anyhow::Result<Vec<[f64; 3]>> {
    s.split(';').map(|t| crate::parse3(t.trim()).map_err(anyhow::Error::msg)).collect()
}

pub fn saccade(a: SaccadeArgs) -> anyhow::Result<ExitCode> {
    let targets = match (&a.orientation, &a.point) {
        (Some(o), None) => parse_list(o)?,
        (None, Some(p)) => parse_list(p)?,
        _ => bail!("give exactly one of --orientation and --point"),
    };
    let torsion = a.torsion;
    let stereo = StereoCalibration::read_yaml(a.calib.join("stereo.yaml"))?;
    let load = |e: &str| FkModel::load(&a.calib.join(e)).with_context(|| format!("{}: FK model", a.calib.display()));
    let models = [load("eye0")?, load("eye1")?];
    let bino = Binocular {
        left: CalibratedIk::new(&models[0]),
        right: CalibratedIk::new(&models[1]),
        left_to_right: Pose::new(stereo.rotation, stereo.translation_mm),
        torsion,
    };
    let mut link = BoardSession::open(&a.port)?;
    let timeout = Duration::from_secs_f64(a.timeout_s);
    // Homing decides during the start-up roll; then wait until the links rest.
    let home = link.wait_homed_at_rest(timeout)?;
    eprintln!("homed: home counts {home:?}");
    // The models' motion history starts where the links are.
    let mut st: [FkState; 2] = [models[0].state(), models[1].state()];
    for e in 0..2 {
        let th = link.latest()[e].deg();
        models[e].eval(&mut st[e], &th, [0.0, 1.0, 0.0])?;
    }
    let mut reports = vec![];
    for target in targets {
        let sol: [[f64; 3]; 2] = match &a.point {
            Some(_) => {
                let [l, r] = &mut st;
                let f = bino.fixate_and_move([l, r], target.map(|v| v * 1000.0), [[0.0, 1.0, 0.0]; 2])?;
                [f.left.ik.theta_deg, f.right.ik.theta_deg]
            }
            None => {
                let mut out = [[0.0; 3]; 2];
                for (e, ik) in [&bino.left, &bino.right].into_iter().enumerate() {
                    out[e] = ik.solve_and_move(&mut st[e], target, [0.0, 1.0, 0.0])?.theta_deg;
                }
                out
            }
        };
        let from: [[f64; 3]; 2] = link.latest().map(|t| t.deg());
        // Both eyes move together (yoked): the slower eye's duration for both.
        let plan = YokedSaccade::plan(from, sol, a.peak_deg_s);
        let (to, target_counts, duration_us) = (plan.to_deg, plan.target_counts, plan.duration_us);
        let m = link.execute(home, target_counts, duration_us, timeout)?;
        let (measured_ms, peak, arrived) = (m.measured_ms, m.peak_deg_s, m.arrived);
        let travel_deg = plan.travel_deg();
        let rep = Report {
            target,
            from_deg: from,
            to_deg: to,
            target_counts,
            travel_deg,
            planned_ms: duration_us as f64 * 1e-3,
            measured_ms,
            peak_deg_s: peak,
            arrived,
        };
        if !a.json {
            println!(
                "saccade to [{:.3}, {:.3}, {:.3}]: link travel {:.2} deg, planned {:.2} ms (minimum jerk, peak {:.0} deg/s); \
                 measured {:.2} / {:.2} ms, peak {:.0} / {:.0} deg/s (left / right){}",
                target[0],
                target[1],
                target[2],
                travel_deg,
                rep.planned_ms,
                a.peak_deg_s,
                measured_ms[0],
                measured_ms[1],
                peak[0],
                peak[1],
                if arrived { "" } else { "; NOT ARRIVED" }
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
            "saccades": reports.iter().map(Report::json).collect::<Vec<_>>(),
            "encoders": stats,
            "homed_samples": link.homed_samples(),
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
    }
    Ok(if reports.iter().all(|r| r.arrived) { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}
