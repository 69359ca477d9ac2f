//! Sinks: where results leave the pipeline inside this process (latency statistics, ground-truth scoring, PNG
//! dumps, recorded sessions).
pub mod dump;
#[cfg(feature = "rerun")]
pub mod rerun_log;
pub mod session_writer;
pub mod stats;
pub mod truth;
