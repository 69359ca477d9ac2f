//! `abvs run`: the runtime's main job. Replays a recorded session (by default the embedded fixture), or runs
//! on the live eyes, through the whole pipeline: time alignment, per-eye FK, moving extrinsic, rectification,
//! disparity, depth and cloud, publishing; prints the latency table and optionally writes the statistics as
//! JSON. The flags make a configuration (`run_args`); the runtime library assembles and runs it
//! ([`abvs_runtime::Runtime`]); this program adds what only the toolkit has (depth scored against a synthetic
//! session's truth, the simulated head: `abvs_sim::head_run`), the signal handling, and the printed report
//! (`run_report`).
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use abvs_runtime::Runtime;
use abvs_runtime_core::config::{RuntimeConfig, SourceKind};
use abvs_sim::head_run::SimHead;
use anyhow::Context;
use clap::ArgMatches;

use crate::run_args::{effective_config, RunArgs};

pub fn run(a: RunArgs, m: &ArgMatches) -> anyhow::Result<ExitCode> {
    let c = effective_config(&a, m)?;
    if a.print_config {
        print!("{}", c.to_toml_string());
        return Ok(ExitCode::SUCCESS);
    }
    run_config(&c)
}

/// Runs one deployment as its configuration describes it.
pub fn run_config(c: &RuntimeConfig) -> anyhow::Result<ExitCode> {
    if c.source.kind == SourceKind::Sim {
        return run_sim(c);
    }
    let mut runtime = Runtime::from_config(c)?;
    // who may move the eyes, said before the first frame (always: a security setting is never quiet)
    eprintln!("{}", runtime.gaze_access());
    abvs_sim::head_run::add_replay_truth(&mut runtime, c)?;
    // from here Ctrl-C / SIGTERM stop the run cleanly (before it: the default, exit)
    let report = runtime.run_until(stop_on_signals()?)?;
    if !c.sinks.quiet {
        crate::run_report::print(c, &report);
    }
    Ok(ExitCode::SUCCESS)
}

/// The closed-loop simulation of the whole head (`source.kind = "sim"`): the head of `[source.sim]`'s seed,
/// its units hybrid-calibrated from simulated measurements (once, kept in `calib_dir`), the runtime on its
/// frames with that calibration, depth and gaze scored against its truth.
fn run_sim(c: &RuntimeConfig) -> anyhow::Result<ExitCode> {
    let head = SimHead::new(c)?;
    let dir = head.calib_dir.display().to_string();
    if !c.sinks.quiet {
        eprintln!("sim: seed {}: units calibrated (hybrid, simulated measurements) in {dir}", c.source.sim.seed);
    }
    head.calibrate().with_context(|| format!("calibrating the simulated units in {dir}"))?;
    let (c, runtime) = head.runtime(c)?;
    let report = runtime.run_until(stop_on_signals()?)?;
    if !c.sinks.quiet {
        crate::run_report::print(&c, &report);
    }
    Ok(ExitCode::SUCCESS)
}

/// A flag set by Ctrl-C (SIGINT) or SIGTERM: the run stops taking frames, finishes those in flight and
/// reports (table, stats JSON) as at its end; a second signal exits at once (status 1).
fn stop_on_signals() -> anyhow::Result<Arc<AtomicBool>> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    let flag = Arc::new(AtomicBool::new(false));
    for sig in [SIGINT, SIGTERM] {
        signal_hook::flag::register_conditional_shutdown(sig, 1, flag.clone())
            .context("installing a signal handler")?;
        signal_hook::flag::register(sig, flag.clone()).context("installing a signal handler")?;
    }
    Ok(flag)
}
