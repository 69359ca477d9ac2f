//! # abvs-calib: forward-kinematics calibration
//!
//! - [`mlp`]: the paper's networks (plain MLP, shared trunk + branches), trained with Adam on
//!   normalised data, evaluated natively; [`onnx_io`] writes and reads them as ONNX.
// Leg/axis-indexed loops read closer to the equations than iterators.
#![allow(clippy::needless_range_loop)]

pub mod error;
pub mod gaze;
pub mod explain;
pub mod identify;
pub mod ik;
pub mod methods;
pub mod metrics;
pub mod mlp;
pub mod model;
pub mod mpe;
pub mod onnx_io;
pub mod paper;
pub mod repeatability;

pub use error::{CalibError, Result};
