//! The calibration crate's error type: abvs-fk's (model files, data, fitting and IK refusals
//! are one vocabulary from the model directory to the calibration that wrote it).
pub use abvs_fk::error::{FkError as CalibError, Result};
