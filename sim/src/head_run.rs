//! The runtime with what only the toolkit has (`abvs run`): depth scored against a synthetic session's truth
//! beside a replay, and the closed-loop simulation of the whole head (`source.kind = "sim"`): the head of
//! `[source.sim]`'s seed ([`crate::head`]), its units hybrid-calibrated from simulated measurements (once, kept
//! in `calib_dir`), the runtime on its frames with that calibration, depth and gaze scored against its truth.
use std::path::PathBuf;

use abvs_runtime::sinks::side_lane::SideLane;
use abvs_runtime::{CustomSource, Runtime};
use abvs_runtime_core::config::RuntimeConfig;
use abvs_runtime_core::error::Result;

use crate::gaze_score::GazeScore;
use crate::gaze_script::GazeScript;
use crate::head::{Head, HeadSpec, SimSource};
use crate::truth::TruthSink;

/// Frames the truth's side lane holds at most (copies of ~7 MB at 640x480): when scoring falls further
/// behind, a frame goes unscored (counted), the pipeline never waits.
pub const TRUTH_COPIES: usize = 8;

/// Adds depth scored against the truth of the session `runtime` replays, when the session has one and
/// `sinks.truth_stride` asks for it.
pub fn add_replay_truth(runtime: &mut Runtime, c: &RuntimeConfig) -> Result<()> {
    if let (true, Some(replay)) = (c.sinks.truth_stride > 0, runtime.replay()) {
        if let Some(t) = TruthSink::for_replay(replay, c.sinks.truth_stride)? {
            // scoring costs about a frame's time: beside the pipeline, at idle priority, never in its path
            runtime.add_sink(Box::new(SideLane::new(t, TRUTH_COPIES, c.source.lossless)?));
        }
    }
    Ok(())
}

/// The simulated head of a configuration, before its calibration.
pub struct SimHead {
    script: Option<GazeScript>,
    head: Head,
    /// Where its units' calibration is kept (`[source.sim] calib_dir`, or one per seed and size under the
    /// temporary directory).
    pub calib_dir: PathBuf,
}

impl SimHead {
    /// The head of `c`'s `[source.sim]`; its gaze script first (a bad line is refused before any work).
    pub fn new(c: &RuntimeConfig) -> Result<SimHead> {
        let sc = &c.source.sim;
        let script = sc.gaze_script.as_deref().map(GazeScript::load).transpose()?;
        let head = Head::new(&HeadSpec::from_config(sc))?;
        let calib_dir = sc.calib_dir.clone().unwrap_or_else(|| {
            std::env::temp_dir().join(format!("abvs-sim-head-{}-{}x{}", sc.seed, sc.width, sc.height))
        });
        Ok(SimHead { script, head, calib_dir })
    }

    /// Calibrates the units (hybrid, from simulated measurements) into `calib_dir`, unless done before.
    pub fn calibrate(&self) -> Result<()> {
        self.head.calibrate(&self.calib_dir, abvs_calib::methods::Method::Hybrid)
    }

    /// The runtime on the head's frames with that calibration (the configuration it runs, `c` with the
    /// calibration directory), depth (when `sinks.truth_stride` asks) and gaze scored against the truth.
    pub fn runtime(self, c: &RuntimeConfig) -> Result<(RuntimeConfig, Runtime)> {
        let sc = &c.source.sim;
        let source = SimSource::new(self.head, self.script)?;
        let (slot, feed, delay) = (source.goal_slot(), source.truth(), source.control_delay_ns());
        let truth = match c.sinks.truth_stride {
            0 => None,
            n => Some(TruthSink::for_head(&source, n)?),
        };
        let mut c = c.clone();
        c.calibration.dir = Some(self.calib_dir);
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
        Ok((c, runtime))
    }
}
