//! The sink contract: where finished frames go (statistics, dumps, the self-check, recordings, and the
//! bridges, sinks whose output leaves the process).
use crate::error::Result;
use crate::messages::Published;
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
}
