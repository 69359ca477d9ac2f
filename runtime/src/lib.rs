//! # abvs-runtime: the perception runtime
//!
//! Grouped by role, data flowing one way (sources -> tasks -> sinks). Built so far:
//! - tasks: [`align`] (encoder samples -> link angles at each frame's mid-exposure time).
//!
//! The rest of the pipeline (capture, encoder serial protocol, per-eye FK, rectification,
//! disparity, publishing) is issue 6.
pub mod align;
pub mod error;

pub use error::{Result, RuntimeError};
