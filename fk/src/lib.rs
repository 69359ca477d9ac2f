//! # abvs-fk: calibrated forward kinematics, as the robot runs it
//!
//! What a calibration writes and the runtime reads, without the training around it:
//! - [`model`]: the model directory format (`manifest.json` + ONNX networks + `unit.toml`) and
//!   [`model::FkModel`], the one evaluator of every method (mh, m1, m2, m1f, m2f, m4f, hybrid,
//!   a foreign ONNX network);
//! - [`net`]: the paper's networks (plain MLP, shared trunk + branches) evaluated natively
//!   (AVX2/FMA kernels at batch 1, GEMM for batches; [`batch`] is the batched pass training
//!   shares);
//! - [`method`]: the calibration methods by name (manifest, command line);
//! - [`onnx_io`]: networks as ONNX files and plain-MLP ONNX graphs as networks;
//! - [`ik`] and [`gaze`]: calibrated inverse kinematics, binocular fixation (Listing's law), the
//!   yoked minimum-jerk saccade plan and smooth pursuit: what pointing the eyes needs on the robot.
//!
//! abvs-calib trains and fits what this crate evaluates; the runtime links only this.
// Leg/axis-indexed loops read closer to the equations than iterators.
#![allow(clippy::needless_range_loop)]

pub mod batch;
pub mod error;
pub mod gaze;
pub mod hash;
pub mod ik;
pub mod method;
pub mod model;
pub mod net;
pub mod onnx_io;

pub use error::{FkError, Result};
pub use method::Method;
