//! Sinks: where results leave the pipeline inside this process (latency statistics, recording, rerun).
pub mod dump;
pub mod stats;
pub mod truth;
