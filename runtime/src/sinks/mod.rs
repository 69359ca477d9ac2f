//! Sinks: where results leave the pipeline inside this process (latency statistics, PNG
//! dumps, recorded sessions). Ground-truth scoring of synthetic sessions is offline: abvs-sim.
pub mod dump;
#[cfg(feature = "rerun")]
pub mod rerun_log;
pub mod self_check;
pub mod session_writer;
pub mod stats;
