//! Sinks: where results leave the pipeline inside this process (latency statistics, ground-truth scoring, PNG dumps).
pub mod dump;
pub mod stats;
pub mod truth;
