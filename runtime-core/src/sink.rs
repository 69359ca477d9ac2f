//! The sink contract: where finished frames go (statistics, dumps, the self-check, recordings, and the
//! bridges, sinks whose output leaves the process).
use crate::error::Result;
use crate::messages::{DepthFrame, Published};
use crate::stats::RunStats;

/// Where finished frames go. Runs on the output lane, after every stage.
pub trait Sink: Send {
    /// The sink's name in the statistics (its failures are counted under it).
    fn name(&self) -> &'static str;
    /// Takes one published frame, on the output lane: the critical path, so it must not block and should not
    /// allocate. An error is that sink's failure, counted; the frame still goes to the others.
    fn consume(&mut self, out: &Published) -> Result<()>;
    /// Adds what the sink measured to the run's statistics.
    fn finish(&mut self, _stats: &mut RunStats) {}
    /// Whether the sink reads the disparity as the engine made it, before the validity mask
    /// ([`Published::dense_disparity`]): the disparity stage then keeps a copy of it, one more map a frame,
    /// so only a sink that scores what the mask removed (the truth of synthetic sessions) asks.
    fn wants_dense_disparity(&self) -> bool {
        false
    }
    /// Offers the sink the frame's depth map and cloud before the output lane's stages fill them: a sink that
    /// sends them in messages lends each its message's buffer ([`crate::lent::LentMap::lend`]), so the depth
    /// stage writes them in place and every sink reads them there. Asked of the sinks in turn until one lends
    /// (returns true); the sink takes the buffers back in [`Sink::frame_done`].
    fn lend_depth(&mut self, _depth: &mut DepthFrame) -> Result<bool> {
        Ok(false)
    }
    /// The frame is done: every sink consumed it (or it failed before they could). A sink that lent the
    /// depth map or cloud its buffer takes it back now (and sends it when it consumed the frame; an unsent buffer
    /// goes back to its pool).
    fn frame_done(&mut self, _depth: &mut DepthFrame) -> Result<()> {
        Ok(())
    }
}
