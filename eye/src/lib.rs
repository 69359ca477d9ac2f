//! # abvs-eye: the one physical model of an SPM eye
//!
//! Everything in abvs that needs the eye's physics uses this crate: the simulator, the
//! calibration methods, the discrepancy workflow and the runtime. Data flows one way:
//!
//! - [`pose`]: Fick angles and the camera pose `P = [alpha, beta, gamma, x, y, z]`.
//! - [`spm`]: the spherical parallel mechanism's kinematics for any leg geometry: closed-form
//!   IK, Newton FK (warm and cold start), Jacobians and the singularity measure.
//! - [`psc`]: the pose sensitivity coefficient of the paper and its workspace map.
//! - [`encoder`]: counts <-> angles and start-up homing on the shared code wheel.
//! - [`saccade`]: minimum-jerk link-space moves at a peak speed (saccades).
//! - `unit`: a real unit = nominal geometry + named physical effects (effects.md); its true FK.
//! - [`dataset`]: calibration dataset files (dataset.md); [`table`]: CSV tables mapped row by row.
//! - [`sim`]: draws plausible units and reproduces the paper's data collection.
//! - [`lm`]: the Levenberg-Marquardt loop both calibrations (FK, camera poses) run.
//!
//! Conventions (frames, angles, units) are those of `shared/spec/conventions.md`: degrees and
//! millimetres in files and on the command line, radians and metres-or-millimetres inside.
// Leg-indexed loops (i over the three legs) read closer to the equations than iterators.
#![allow(clippy::needless_range_loop)]

pub mod dataset;
pub mod encoder;
pub mod error;
pub mod lm;
pub mod pose;
pub mod psc;
pub mod saccade;
pub mod sim;
pub mod spm;
pub mod table;
pub mod unit;

pub use error::{EyeError, Result};
pub use pose::{Fick, Pose};
pub use spm::{FkSolver, SpmGeometry};
pub use unit::UnitModel;

/// Paper workspace limits, degrees: pitch (alpha), roll (beta), yaw (gamma).
pub const WORKSPACE_DEG: [f64; 3] = [30.0, 15.0, 30.0];
