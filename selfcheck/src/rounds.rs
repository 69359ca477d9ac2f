//! The timing analysis of a log: its fit, and, when the log is of a replay whose session is still there, the
//! replay run again with each estimate and fitted again while the correction is large (the fit's model is
//! first order: far from the truth it only points the way).
use std::path::{Path, PathBuf};

use abvs_runtime::sinks::self_check::log_record::{match_log_path, run_config_path, run_header, sha256_hex};
use abvs_runtime_core::config::{RuntimeConfig, SourceKind};
use abvs_runtime_core::session::TimeOffsetMs;
use abvs_runtime_core::session::SESSION_FILE;

use crate::error::{Result, SelfCheckError};
use crate::timing_fit::{fit, offset_setting, round2, TimingFit};
use crate::timing_log::{
    not_as_applied, read_frames, read_frames_with_timing, read_matches_of_run, same_run, FrameTiming,
};

/// What the timing analysis of a log found.
#[derive(Debug, Clone)]
pub struct TimingAnalysis {
    /// The logs fitted, with their frames: the given log, then each round's (empty when the log has no timing
    /// columns).
    pub logs: Vec<(PathBuf, Vec<FrameTiming>)>,
    /// The estimate, or why there is none.
    pub outcome: TimingOutcome,
}

/// The estimate, or why there is none.
#[derive(Debug, Clone)]
pub enum TimingOutcome {
    /// No estimate, and why (for a person: "no estimate: {reason}").
    NoEstimate(String),
    /// The fits, the given log's first, the last the estimate to apply.
    Estimated {
        /// One per log fitted ([`TimingAnalysis::logs`]).
        fits: Vec<TimingFit>,
        /// Why no rounds ran although the correction was large (not a replay, its session gone, ...).
        no_rounds: Option<String>,
    },
}

/// Estimates the eyes' timing from the self-check log `log` (and its match log). With `rounds` > 0 and a
/// large correction, a log of a replay is replayed again with each estimate (up to `rounds` times, each
/// round's log written into `out`); `progress` hears of each round before it runs.
pub fn analyse(log: &Path, rounds: u32, out: &Path, progress: &mut dyn FnMut(&str)) -> Result<TimingAnalysis> {
    let none = |logs, reason: &str| TimingAnalysis { logs, outcome: TimingOutcome::NoEstimate(reason.to_string()) };
    let Some(frames) = read_frames(log)? else {
        return Ok(none(Vec::new(), "the log has no timing columns (written by an abvs before the timing evidence)"));
    };
    let mut logs = vec![(log.to_path_buf(), frames.clone())];
    let mpath = match_log_path(log);
    if !mpath.exists() {
        let why = format!("no match log {} (the run had no raw cameras for the evidence)", mpath.display());
        return Ok(none(logs, &why));
    }
    let (matches, mrun) = read_matches_of_run(&mpath)?;
    let run = same_run(log, &frames, &mpath, mrun)?;
    if let Some(why) = not_as_applied(&frames) {
        return Ok(none(logs, &why));
    }
    let Some(first) = fit(&frames, &matches)? else {
        return Ok(none(
            logs,
            "too few frames in which the eyes moved steadily (at least 10 with matches, faster than 5 deg/s): \
             record a minute of pursuit with the eyes verging",
        ));
    };
    let mut fits = vec![first];
    let mut no_rounds = None;
    let replay = if rounds > 0 && fits[0].refine() {
        match replay_config(log, run)? {
            Ok(c) => Some(c),
            Err(why) => {
                no_rounds = Some(why);
                None
            }
        }
    } else {
        None
    };
    if let Some(cfg) = &replay {
        for k in 1..=rounds {
            let prev = fits.last().expect("one fit");
            if !prev.refine() {
                break;
            }
            let log = out.join(format!("round-{k}.csv"));
            // what the round applies, as the replay reads it (per eye where the estimate is per eye)
            let applied = match offset_setting(prev) {
                TimeOffsetMs::Both(v) => format!("offset {v:.2} ms (both eyes)"),
                TimeOffsetMs::PerEye([l, r]) => format!("offsets {l:.2} ms left, {r:.2} ms right"),
            };
            progress(&format!(
                "timing: round {k}: replaying {} with {applied}, readout {:.2} ms",
                cfg.source.session.as_deref().unwrap_or(Path::new("?")).display(),
                round2(prev.readout.value.max(0.0))
            ));
            rerun(cfg, prev, &log)?;
            let frames = read_frames_with_timing(&log)?;
            let mp = match_log_path(&log);
            let (matches, mrun) = read_matches_of_run(&mp)?;
            same_run(&log, &frames, &mp, mrun)?;
            let Some(t) = fit(&frames, &matches)? else { break };
            fits.push(t);
            logs.push((log, frames));
        }
    }
    Ok(TimingAnalysis { logs, outcome: TimingOutcome::Estimated { fits, no_rounds } })
}

/// The configuration a log's run used (`<log>.run.toml`), when it names the log's run, is as the run wrote it
/// (its SHA-256) and replayed a session that is still there as the run read it (its session.toml's SHA-256);
/// otherwise why the rounds cannot run.
pub fn replay_config(log: &Path, run: Option<u64>) -> Result<std::result::Result<RuntimeConfig, String>> {
    let p = run_config_path(log);
    if !p.exists() {
        return Ok(Err(format!("no {} beside the log (its run's configuration): nothing to replay", p.display())));
    }
    let text = std::fs::read_to_string(&p).map_err(|source| SelfCheckError::Io { path: p.clone(), source })?;
    let header = run_header(&text).map_err(|value| SelfCheckError::RunIdNotANumber { path: p.clone(), value })?;
    if let (Some(a), Some(b)) = (run, header.run_id) {
        if a != b {
            return Ok(Err(format!(
                "{} is of run {b}, the log of run {a}: not replayed (another run's configuration)",
                p.display()
            )));
        }
    }
    if !header.config_intact {
        return Ok(Err(format!(
            "{} was edited after its run (its configuration's SHA-256 is not the one the run wrote): not replayed",
            p.display()
        )));
    }
    let c = RuntimeConfig::load(&p)?;
    if c.source.kind != SourceKind::Session {
        return Ok(Err(format!("{}: a live run, not a replay: record another minute with the estimate", p.display())));
    }
    match c.source.session.as_deref() {
        Some(d) if d.join(SESSION_FILE).exists() => {
            // the session the run replayed, as it read it: not another one, nor one rendered again there
            let s = d.join(SESSION_FILE);
            let bytes = std::fs::read(&s).map_err(|source| SelfCheckError::Io { path: s.clone(), source })?;
            match header.session_sha256 {
                Some(h) if h != sha256_hex(&bytes) => Ok(Err(format!(
                    "{}: {} is not the session the run replayed (its SHA-256 differs from the one the run read: \
                     another session, or changed since): not replayed",
                    p.display(),
                    s.display()
                ))),
                _ => Ok(Ok(c)),
            }
        }
        d => Ok(Err(format!(
            "{}: its session {} is not there any more",
            p.display(),
            d.map_or("(none)".into(), |d| d.display().to_string())
        ))),
    }
}

/// Replays `cfg`'s session with `t`'s timing, lossless, nothing published, the self-check logging to `log`.
pub fn rerun(cfg: &RuntimeConfig, t: &TimingFit, log: &Path) -> Result<()> {
    let mut c = cfg.clone();
    c.motion.time_offset_ms = Some(offset_setting(t));
    c.motion.readout_ms = Some(round2(t.readout.value.max(0.0)));
    c.source.lossless = true;
    c.source.paced = false;
    c.bridges.iceoryx.enabled = false;
    c.bridges.zenoh.enabled = false;
    c.sinks.mcap.file = None;
    c.sinks.stats_json = None;
    c.sinks.dump = None;
    c.sinks.rerun = None;
    c.sinks.quiet = true;
    c.sinks.self_check.enabled = true;
    c.sinks.self_check.log = Some(log.to_path_buf());
    abvs_runtime::Runtime::from_config(&c)?.run()?;
    Ok(())
}
