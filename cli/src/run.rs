//! `abvs run`: the runtime's main job. Replays a recorded session (by default the embedded fixture), or runs
//! on the live eyes, through the whole pipeline: time alignment, per-eye FK, moving extrinsic, rectification,
//! disparity, depth and cloud, publishing; prints the latency table and optionally writes the statistics as
//! JSON. The flags make a configuration (`run_args`); the runtime library assembles and runs it
//! ([`abvs_runtime::Runtime`]); this program adds what only the toolkit has (depth scored against a synthetic
//! session's truth), the signal handling, and the printed report (`run_report`).
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use abvs_runtime::config::RuntimeConfig;
use abvs_runtime::sinks::side_lane::SideLane;
use abvs_runtime::Runtime;
use abvs_sim::truth::TruthSink;
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

/// Frames the truth's side lane holds at most (copies of ~7 MB at 640x480): when scoring falls further
/// behind, a frame goes unscored (counted), the pipeline never waits.
const TRUTH_COPIES: usize = 8;

/// Runs one deployment as its configuration describes it.
pub fn run_config(c: &RuntimeConfig) -> anyhow::Result<ExitCode> {
    let mut runtime = Runtime::from_config(c)?;
    // who may move the eyes, said before the first frame (always: a security setting is never quiet)
    eprintln!("{}", runtime.gaze_access());
    if let (true, Some(replay)) = (c.sinks.truth_stride > 0, runtime.replay()) {
        if let Some(t) = TruthSink::for_replay(replay, c.sinks.truth_stride)? {
            // scoring costs about a frame's time: beside the pipeline, at idle priority, never in its path
            runtime.add_sink(Box::new(SideLane::new(t, TRUTH_COPIES, c.source.lossless)?));
        }
    }
    // from here Ctrl-C / SIGTERM stop the run cleanly (before it: the default, exit)
    let report = runtime.run_until(stop_on_signals()?)?;
    if !c.sinks.quiet {
        crate::run_report::print(c, &report);
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
