//! # abvs-runtime: the perception runtime
//!
//! Grouped by role, data flowing one way (sources -> tasks -> sinks). Built so far:
//! - sources: [`encoder_link`] (the drive board's framed serial protocol, clock mapping).
//! - tasks: [`align`] (encoder samples -> link angles at each frame's mid-exposure time).
//!
//! The rest of the pipeline (capture, homing on the live stream, per-eye FK, rectification,
//! disparity, publishing) is issue 6.
pub mod align;
pub mod encoder_link;
pub mod error;

pub use error::{Result, RuntimeError};
