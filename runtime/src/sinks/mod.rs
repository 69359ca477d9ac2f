//! Sinks: where results leave the pipeline inside this process (latency statistics, PNG
//! dumps, recorded sessions, MCAP recordings of the ROS 2 messages). Ground-truth scoring of synthetic sessions is offline: abvs-sim.
pub mod dump;
pub mod mcap_log;
#[cfg(feature = "rerun")]
pub mod rerun_log;
pub mod ros2_out;
pub mod self_check;
pub mod session_writer;
pub mod side_lane;
/// The run's statistics (moved to [`crate::stats`]; the path sinks have always used still works).
pub use crate::stats;

use crate::error::Result;
pub use crate::messages::Published;
use crate::stats::RunStats;

/// Where finished frames go: statistics, dumps, the self-check, iceoryx2 publishing (a bridge is a sink
/// whose output leaves the process). Runs on the output lane, after every stage.
pub trait Sink: Send {
    /// The sink's name in the statistics (its failures are counted under it).
    fn name(&self) -> &'static str;
    /// Takes one published frame, on the output lane: the critical path, so it must not block and should not
    /// allocate. An error is that sink's failure, counted; the frame still goes to the others.
    fn consume(&mut self, out: &Published) -> Result<()>;
    /// Adds what the sink measured to the run's statistics.
    fn finish(&mut self, _stats: &mut RunStats) {}
}
