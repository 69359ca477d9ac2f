//! Sinks: where results leave the pipeline inside this process (latency statistics, recording, rerun).
