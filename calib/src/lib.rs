//! # abvs-calib: forward-kinematics calibration
//!
//! - [`mlp`]: training of the paper's networks (plain MLP, shared trunk + branches) with Adam
//!   on normalised data; the networks, their evaluation, ONNX files and the model directory
//!   format are abvs-fk's ([`model`], [`onnx_io`] re-exported).
// Leg/axis-indexed loops read closer to the equations than iterators.
#![allow(clippy::needless_range_loop)]

pub mod error;
pub mod explain;
pub mod gaze;
pub mod identify;
pub mod ik;
pub mod methods;
pub mod metrics;
pub mod mlp;
pub mod mpe;
pub mod repeatability;

/// The model directory format and the FkModel evaluator live in abvs-fk (what the robot links).
pub use abvs_fk::{model, onnx_io};
pub use error::{CalibError, Result};
