//! # abvs-calib: forward-kinematics calibration
//!
//! - [`mlp`]: training of the paper's networks (plain MLP, shared trunk + branches) with Adam
//!   on normalised data; the networks, their evaluation, ONNX files and the model directory
//!   format are abvs-fk's ([`model`], [`onnx_io`] re-exported).
// Leg/axis-indexed loops read closer to the equations than iterators.
#![allow(clippy::needless_range_loop)]

pub mod demo;
pub mod error;
pub mod explain;
pub mod identify;
pub mod methods;
pub mod metrics;
pub mod mlp;
pub mod mpe;
pub mod repeatability;

/// The model directory format, the FkModel evaluator, calibrated IK and gaze live in abvs-fk (what the
/// robot links: the runtime points the eyes with them).
pub use abvs_fk::{gaze, ik, model, onnx_io};
pub use error::{CalibError, Result};
