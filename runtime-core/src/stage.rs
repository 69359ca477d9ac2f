//! The stage contract: what every processing step between a source and the sinks implements (align,
//! kinematics, rectify, disparity, depth, and any side stage). The runtime's runner calls
//! [`Stage::start`] once before the first frame, [`Stage::process`] on every frame of its lane's thread, and
//! [`Stage::finish`] once after the last; a stage owns its state (tracks, models, maps, engines) and writes
//! its message into the frame's pooled buffers, so processing does not allocate.
use crate::error::{Result, RuntimeError};
use crate::messages::{RectifiedCamera, Work};
use crate::source::{BoardLink, EncoderFeed};
use crate::stats::RunStats;

/// What a stage learns of the run at its start.
pub struct StageContext<'a> {
    /// Raw frame size (both eyes), from the source.
    pub raw: (u32, u32),
    /// The rectified output every stage after rectification works at.
    pub out: RectifiedCamera,
    /// The source's encoder stream, taken by the stage that aligns frames to it.
    pub encoders: &'a mut Option<Box<dyn EncoderFeed>>,
    /// The drive board's command side (live sources), taken by the gaze stage.
    pub board: &'a mut Option<Box<dyn BoardLink>>,
}

/// One processing step of the graph (see the module docs for when the runner calls what).
pub trait Stage: Send {
    /// The stage's name in a graph description.
    fn name(&self) -> &'static str;
    /// Checks the graph's geometry and takes what the stage needs from the run; called on the runner's
    /// thread before any frame. An error refuses the run.
    fn start(&mut self, _ctx: &mut StageContext) -> Result<()> {
        Ok(())
    }
    /// Sizes the buffers this stage writes in one pooled frame beyond those every frame has (e.g. the
    /// disparity stage's confidence, when it computes one). Called once per pooled frame at start-up, before
    /// [`Stage::start`]; the default adds nothing.
    fn prepare_work(&self, _w: &mut Work) {}
    /// Reads the messages of earlier stages from `w` and writes its own. An error drops the frame, counted
    /// under [`Stage::failure`].
    fn process(&mut self, w: &mut Work) -> Result<()>;
    /// The counter a failed frame is counted under (static: counting must not allocate).
    fn failure(&self, e: &RuntimeError) -> &'static str {
        timing_failure(e).unwrap_or("stage failed")
    }
    /// Whether the stage writes the frame's depth, which only the output lane lends (see [`Work::depth`]):
    /// the runner refuses a graph that puts such a stage elsewhere.
    fn needs_output_lane(&self) -> bool {
        false
    }
    /// Whether the stage bounds the pipeline's frame rate (the disparity engine): its lane keeps the normal
    /// scheduling priority and the lanes without such a stage step back a little (see the runner).
    fn bottleneck(&self) -> bool {
        false
    }
    /// Lets a frame pass without the stage's work, when its lane is behind (a newer frame already waits for
    /// it) and the run is not lossless; returns whether it did. For a stage whose product is an extra that a
    /// frame may go without (the fovea): a late extra then costs that frame's extra, not the frame. The
    /// default never sheds: the frame is processed.
    fn shed(&mut self, _w: &mut Work) -> bool {
        false
    }
    /// Adds what the stage counted to the run's statistics.
    fn finish(&mut self, _stats: &mut RunStats) {}
}

/// Counter names of the time-alignment faults, which every stage reading encoder time may hit.
pub fn timing_failure(e: &RuntimeError) -> Option<&'static str> {
    match e {
        RuntimeError::OutOfSpan { .. } => Some("encoders do not cover the frame time"),
        RuntimeError::Gap { .. } => Some("gap in the encoder stream"),
        RuntimeError::NonMonotonic { .. } => Some("non-monotonic timestamps"),
        _ => None,
    }
}
