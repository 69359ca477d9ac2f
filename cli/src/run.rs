//! `abvs run`: the runtime's main job. Replays a recorded session (by default the embedded fixture), or runs
//! on the live eyes, through the whole pipeline: time alignment, per-eye FK, moving extrinsic, rectification,
//! disparity, depth and cloud, publishing; prints the latency table and optionally writes the statistics as
//! JSON. The flags make a configuration (`run_args`); the runtime library assembles and runs it
//! ([`abvs_runtime::Runtime`]); this program adds what only the toolkit has (depth scored against a synthetic
//! session's truth), the signal handling, and the printed report (`run_report`).
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use abvs_runtime::sinks::side_lane::SideLane;
use abvs_runtime::{CustomSource, Runtime};
use abvs_runtime_core::config::{RuntimeConfig, SourceKind};
use abvs_sim::gaze_score::GazeScore;
use abvs_sim::gaze_script::GazeScript;
use abvs_sim::head::{Head, HeadSpec, SimSource};
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
    if c.source.kind == SourceKind::Sim {
        return run_sim(c);
    }
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

/// The closed-loop simulation of the whole head (`source.kind = "sim"`): the head of `[source.sim]`'s seed,
/// its units hybrid-calibrated from simulated measurements (once, kept in `calib_dir`), the runtime on its
/// frames with that calibration, depth and gaze scored against its truth.
fn run_sim(c: &RuntimeConfig) -> anyhow::Result<ExitCode> {
    let sc = &c.source.sim;
    // the script first: a bad line is refused before any work
    let script = sc.gaze_script.as_deref().map(GazeScript::load).transpose()?;
    let spec = HeadSpec::from_config(sc);
    let head = Head::new(&spec)?;
    let dir = sc
        .calib_dir
        .clone()
        .unwrap_or_else(|| std::env::temp_dir().join(format!("abvs-sim-head-{}-{}x{}", sc.seed, sc.width, sc.height)));
    if !c.sinks.quiet {
        eprintln!("sim: seed {}: units calibrated (hybrid, simulated measurements) in {}", sc.seed, dir.display());
    }
    head.calibrate(&dir, abvs_calib::methods::Method::Hybrid)
        .with_context(|| format!("calibrating the simulated units in {}", dir.display()))?;
    let source = SimSource::new(head, script)?;
    let (slot, feed, delay) = (source.goal_slot(), source.truth(), source.control_delay_ns());
    let truth = match c.sinks.truth_stride {
        0 => None,
        n => Some(TruthSink::for_head(&source, n)?),
    };
    let mut c = c.clone();
    c.calibration.dir = Some(dir);
    let name = format!(
        "sim: seed {}, {}x{} at {} fps, exposure {} ms, readout {} ms{}",
        sc.seed,
        sc.width,
        sc.height,
        sc.fps,
        sc.exposure_ms,
        sc.readout_ms,
        sc.gaze_script.as_ref().map(|p| format!(", gaze script {}", p.display())).unwrap_or_default()
    );
    let custom = CustomSource { source: Box::new(source), readout_ms: sc.readout_ms, name };
    let mut runtime = Runtime::with_source(&c, custom)?;
    let _ = slot.set(runtime.gaze());
    if let Some(t) = truth {
        // lossless: the side lane waits for scoring, every frame is scored
        runtime.add_sink(Box::new(SideLane::new(t, TRUTH_COPIES, true)?));
    }
    runtime.add_sink(Box::new(GazeScore::new(feed, delay)));
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
