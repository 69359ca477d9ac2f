//! `abvs`: the one command-line program of the project. Each subcommand is a thin shell over a
//! library crate (abvs-eye for the physics, abvs-onnx for ONNX Runtime).
mod calib;
mod camcal;
mod demo;
mod disparity;
mod disparity_eval;
mod echo;
mod explain;
mod explain_plots;
mod gaze;
mod kin;
mod logger;
mod paper;
mod pfm;
mod plot;
mod record;
mod repeat;
mod run;
mod saccade;
mod self_check_report;
mod sim;
mod table;

use clap::{CommandFactory, FromArgMatches, Subcommand};
use std::process::ExitCode;

#[derive(clap::Parser)]
#[command(name = "abvs", version, about = "Perception runtime and calibration tools for SPM robot eyes")]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

// Parsed once per process: the size of the largest variant does not matter.
#[allow(clippy::large_enum_variant)]
#[derive(Subcommand)]
enum Cmd {
    /// Simulate units and the paper's data collection.
    #[command(subcommand)]
    Sim(sim::SimCmd),
    /// Nominal / unit kinematics on CSV files (IK, FK, PSC map).
    #[command(subcommand)]
    Kin(kin::KinCmd),
    /// Calibrate forward kinematics: fit, fine-tune, evaluate, predict.
    #[command(subcommand)]
    Calib(calib::CalibCmd),
    /// Point both eyes: fixate a 3D point with the calibrated models (calibrated IK of each eye).
    #[command(subcommand)]
    Gaze(gaze::GazeCmd),
    /// The main job on the embedded default unit: simulate, measure, compare, map.
    Demo(demo::DemoArgs),
    /// The runtime: replay a session (default: the embedded fixture) through the whole pipeline.
    Run(run::RunArgs),
    /// Record a session from the eye cameras (V4L2) and the drive board's encoders (serial), homing first.
    Record(record::RecordArgs),
    /// Subscribe to the runtime's depth or cloud (iceoryx2) and print rate and latency.
    Echo(echo::EchoArgs),
    /// Left-view disparity of a rectified pair with the shipped network or SGBM, written as PFM.
    Disparity(disparity::DisparityArgs),
    /// Score the disparity engines (each model variant and SGBM) against a ground-truth map, with timing.
    DisparityEval(disparity_eval::EvalArgs),
    /// Report what abvs found on this machine (ONNX Runtime library, version).
    Doctor,
}

fn main() -> ExitCode {
    logger::init();
    // The matches tell `abvs run` which flags were given (they override its --config file).
    let matches = Cli::command().get_matches();
    let cli = Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
    // Rust ignores SIGPIPE, so a closed pipe (`abvs calib stereo ... | head -1`) made println! panic: the
    // offline tools end as the pipe's reader asked, like other Unix tools. Not the processes that talk to
    // sockets, serial links and subscribers (run, record, echo, gaze, sim): a consumer going away must be an
    // error they handle, never a signal that kills them.
    if !matches!(cli.cmd, Cmd::Run(_) | Cmd::Record(_) | Cmd::Echo(_) | Cmd::Gaze(_) | Cmd::Sim(_)) {
        // SAFETY: before any thread is started; SIG_DFL is a valid disposition for SIGPIPE.
        unsafe {
            libc::signal(libc::SIGPIPE, libc::SIG_DFL);
        }
    }
    let r = match cli.cmd {
        Cmd::Sim(c) => sim::run(c),
        Cmd::Kin(c) => kin::run(c),
        Cmd::Calib(c) => calib::run(c),
        Cmd::Gaze(c) => gaze::run(c),
        Cmd::Demo(a) => demo::run(a),
        Cmd::Run(a) => run::run(a, matches.subcommand_matches("run").expect("the run subcommand")),
        Cmd::Record(a) => record::run(a),
        Cmd::Echo(a) => echo::run(a),
        Cmd::Disparity(a) => disparity::run_disparity(a),
        Cmd::DisparityEval(a) => disparity_eval::run_eval(a),
        Cmd::Doctor => doctor(),
    };
    match r {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn doctor() -> anyhow::Result<ExitCode> {
    println!("abvs {}", env!("CARGO_PKG_VERSION"));
    match abvs_onnx::init() {
        Ok(info) => {
            println!("onnxruntime: {}", info.path.display());
            println!("onnxruntime build: {}", info.build_info);
            Ok(ExitCode::SUCCESS)
        }
        Err(e) => {
            println!("onnxruntime: NOT FOUND ({e})");
            Ok(ExitCode::FAILURE)
        }
    }
}

/// Progress bar on stderr for long work (hidden when stderr is not a terminal).
pub fn progress_bar(total: u64, what: &str) -> indicatif::ProgressBar {
    let pb = indicatif::ProgressBar::new(total);
    pb.set_style(
        indicatif::ProgressStyle::with_template("{msg:>12} [{bar:40}] {pos}/{len} ({eta})")
            .expect("valid template")
            .progress_chars("=> "),
    );
    pb.set_message(what.to_string());
    pb
}

/// Parses "a,b,c" into three numbers.
pub fn parse3(s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>().map_err(|_| format!("'{x}' is not a number")))
        .collect::<Result<_, _>>()?;
    v.try_into().map_err(|_| format!("'{s}': expected three comma-separated numbers"))
}
