//! Tasks: the processing stages between sources and sinks.
pub mod align;
