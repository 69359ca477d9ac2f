//! `abvs`: the one command-line program of the project. Each subcommand is a thin shell over a
//! library crate (abvs-eye for the physics, abvs-onnx for ONNX Runtime).
mod args;
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
mod plot;
mod record;
mod repeat;
mod run;
mod run_args;
mod run_report;
mod saccade;
mod self_check_report;
mod self_check_timing;
mod sim;
mod table;

use clap::{CommandFactory, FromArgMatches, Subcommand};
use std::process::ExitCode;

#[derive(clap::Parser)]
#[command(name = "abvs", version, about = "Perception runtime and calibration tools for SPM robot eyes")]
struct Cli {
    /// Testing: parse and check the arguments (ranges, sizes, output paths), then exit 0 without
    /// doing the work (cli/tests/doors.rs knocks on every flag this way).
    #[arg(long, hide = true)]
    validate_only: bool,
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
    Run(run_args::RunArgs),
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
    /// Testing: every subcommand's arguments as JSON (cli/tests/doors.rs).
    #[command(hide = true)]
    CliTree,
    /// Testing: checks many command lines in one process as `--validate-only` does (one JSON array of
    /// arguments per stdin line; one JSON answer per line: code 0 accepted, 1 refused by a check, 2 refused
    /// by clap, 101 panicked; the refusal; milliseconds), so cli/tests/doors.rs knocks on hundreds of doors
    /// without starting hundreds of processes.
    #[command(hide = true)]
    ValidateLines,
}

/// The command tree as every entry point parses it. A number after a space is the value of the flag before
/// it, a negative one too: `--readout-ms -5` reaches the flag's own range check (which names it) instead of
/// clap's "unexpected argument '-5'". Only words that read as numbers: `--out -x` still reads `-x` as a flag.
fn command() -> clap::Command {
    fn negatives(c: clap::Command) -> clap::Command {
        // flags that take no value (switches) cannot take a number either (clap asserts it)
        c.mut_args(|a| if a.get_action().takes_values() { a.allow_negative_numbers(true) } else { a })
            .mut_subcommands(negatives)
    }
    negatives(Cli::command())
}

/// Checks that need several flags together or the file system (grid sizes, output paths): after
/// clap's per-flag checks and before any work.
fn check(cmd: &Cmd) -> anyhow::Result<()> {
    match cmd {
        Cmd::Kin(kin::KinCmd::Psc(a)) => a.check(),
        Cmd::Sim(sim::SimCmd::Dataset(a)) => a.check(),
        Cmd::Sim(sim::SimCmd::Session(a)) => a.check(),
        Cmd::Demo(a) => a.check(),
        Cmd::Calib(c) => c.check(),
        Cmd::Run(a) => a.check(),
        Cmd::Record(a) => a.check(),
        _ => Ok(()),
    }
}

fn main() -> ExitCode {
    logger::init();
    // The matches tell `abvs run` which flags were given (they override its --config file).
    let matches = command().get_matches();
    let cli = Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
    if let Err(e) = check(&cli.cmd) {
        eprintln!("error: {}", message(&e));
        return ExitCode::FAILURE;
    }
    if cli.validate_only {
        return ExitCode::SUCCESS;
    }
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
        Cmd::CliTree => {
            println!("{}", cli_tree(&command()));
            Ok(ExitCode::SUCCESS)
        }
        Cmd::ValidateLines => validate_lines(),
    };
    match r {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {}", message(&e));
            ExitCode::FAILURE
        }
    }
}

/// The error and its causes on one line, each said once: typed errors print their OS error in
/// their own message and also return it as their source.
fn message(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for c in e.chain() {
        let s = c.to_string();
        if out.contains(&s) {
            continue;
        }
        if !out.is_empty() {
            out += ": ";
        }
        out += &s;
    }
    out
}

/// `abvs validate-lines`: clap's parse and `check` of each line's arguments, a panic caught and reported.
fn validate_lines() -> anyhow::Result<ExitCode> {
    use std::io::{BufRead, Write};
    let mut out = std::io::stdout().lock();
    for line in std::io::stdin().lock().lines() {
        let argv: Vec<String> = serde_json::from_str(&line?)?;
        let t0 = std::time::Instant::now();
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            let m = command()
                .try_get_matches_from(std::iter::once("abvs".to_string()).chain(argv))
                .map_err(|e| (e.exit_code(), e.render().to_string()))?;
            let cli = Cli::from_arg_matches(&m).map_err(|e| (2, e.render().to_string()))?;
            check(&cli.cmd).map_err(|e| (1, format!("error: {}", message(&e))))
        }));
        let (code, error) = match r {
            Ok(Ok(())) => (0, String::new()),
            Ok(Err(e)) => e,
            Err(_) => (101, "panicked".to_string()),
        };
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        writeln!(out, "{}", serde_json::json!({"code": code, "error": error, "ms": ms}))?;
        out.flush()?;
    }
    Ok(ExitCode::SUCCESS)
}

/// The kind of value an argument's parser yields, as the door-knocking test feeds it.
fn value_kind(a: &clap::Arg) -> &'static str {
    use std::any::TypeId;
    let t = a.get_value_parser().type_id();
    let is = |id: TypeId| t == id;
    if [TypeId::of::<f64>(), TypeId::of::<f32>()].into_iter().any(is) {
        "float"
    } else if [
        TypeId::of::<u8>(),
        TypeId::of::<u16>(),
        TypeId::of::<u32>(),
        TypeId::of::<u64>(),
        TypeId::of::<usize>(),
        TypeId::of::<i32>(),
        TypeId::of::<i64>(),
    ]
    .into_iter()
    .any(is)
    {
        "int"
    } else if is(TypeId::of::<[f64; 3]>()) {
        "vec3"
    } else if is(TypeId::of::<[f64; 2]>()) || is(TypeId::of::<(f64, f64)>()) {
        "vec2"
    } else if a.get_action().takes_values() {
        "other"
    } else {
        "flag"
    }
}

/// Every leaf subcommand with its arguments: path, flag, kind, required, defaults, choices,
/// conflicts, help present; and the groups (one of a required group must be given).
fn cli_tree(root: &clap::Command) -> serde_json::Value {
    fn walk(c: &clap::Command, path: &mut Vec<String>, out: &mut Vec<serde_json::Value>) {
        if c.is_hide_set() {
            return;
        }
        if c.has_subcommands() {
            for s in c.get_subcommands().filter(|s| s.get_name() != "help") {
                path.push(s.get_name().to_string());
                walk(s, path, out);
                path.pop();
            }
            return;
        }
        let name = |a: &clap::Arg| match a.get_long() {
            Some(l) => format!("--{l}"),
            None => a.get_id().to_string(),
        };
        let args: Vec<serde_json::Value> = c
            .get_arguments()
            .filter(|a| !matches!(a.get_id().as_str(), "help" | "version"))
            .map(|a| {
                serde_json::json!({
                    "id": a.get_id().as_str(),
                    "name": name(a),
                    "positional": a.is_positional(),
                    "kind": value_kind(a),
                    "required": a.is_required_set(),
                    "hidden": a.is_hide_set(),
                    "help": a.get_help().or(a.get_long_help()).map(|h| h.to_string()),
                    "defaults": a.get_default_values().iter().map(|v| v.to_string_lossy()).collect::<Vec<_>>(),
                    "choices": a.get_possible_values().iter().map(|v| v.get_name().to_string()).collect::<Vec<_>>(),
                    "conflicts": c.get_arg_conflicts_with(a).iter().map(|b| b.get_id().as_str()).collect::<Vec<_>>(),
                })
            })
            .collect();
        let groups: Vec<serde_json::Value> = c
            .get_groups()
            .map(|g| {
                serde_json::json!({
                    "required": g.is_required_set(),
                    "multiple": g.clone().is_multiple(),
                    "args": g.get_args().map(|i| i.as_str()).collect::<Vec<_>>(),
                })
            })
            .collect();
        out.push(serde_json::json!({"path": path.clone(), "args": args, "groups": groups}));
    }
    let mut root = root.clone();
    root.build();
    let mut out = Vec::new();
    walk(&root, &mut Vec::new(), &mut out);
    serde_json::Value::Array(out)
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

/// A `(done, total)` progress callback that moves `pb`.
pub fn progress_to(pb: &indicatif::ProgressBar) -> impl FnMut(usize, usize) + '_ {
    |done, total| {
        pb.set_length(total as u64);
        pb.set_position(done as u64)
    }
}

/// Parses "a,b,c;a,b,c;..." into triples of finite numbers.
pub fn parse_list(s: &str) -> anyhow::Result<Vec<[f64; 3]>> {
    s.split(';').map(|t| args::vec3(t.trim()).map_err(anyhow::Error::msg)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every flag of every subcommand explains itself (hidden testing flags included), and
    /// every subcommand says what it does.
    #[test]
    fn every_help_line_has_a_description() {
        fn walk(c: &clap::Command, path: &str, missing: &mut Vec<String>) {
            for a in c.get_arguments().filter(|a| !matches!(a.get_id().as_str(), "help" | "version")) {
                if a.get_help().or(a.get_long_help()).is_none_or(|h| h.to_string().trim().is_empty()) {
                    missing.push(format!("{path} {}", a.get_long().unwrap_or(a.get_id().as_str())));
                }
            }
            for s in c.get_subcommands().filter(|s| s.get_name() != "help") {
                if s.get_about().is_none() {
                    missing.push(format!("{path} {} (the subcommand)", s.get_name()));
                }
                walk(s, &format!("{path} {}", s.get_name()), missing);
            }
        }
        let mut root = command();
        root.build();
        let mut missing = Vec::new();
        walk(&root, "abvs", &mut missing);
        assert!(missing.is_empty(), "flags without a description:\n{}", missing.join("\n"));
    }

    #[test]
    fn os_errors_are_said_once() {
        let io = std::io::Error::from(std::io::ErrorKind::NotFound);
        let text = io.to_string();
        let e = anyhow::Error::new(abvs_eye::EyeError::io("/x.csv", io)).context("reading the data");
        let m = message(&e);
        assert_eq!(m.matches(&text).count(), 1, "{m}");
        assert!(m.starts_with("reading the data: /x.csv"), "{m}");
    }

    #[test]
    fn the_tree_lists_numeric_flags() {
        let t = cli_tree(&command()).to_string();
        assert!(t.contains(r#""name":"--step-deg""#) && t.contains(r#""kind":"float""#), "{t}");
    }
}
