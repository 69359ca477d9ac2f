//! `abvs-camcal`: camera calibration from images. AprilGrid and chessboard detection
//! ([`detect`], [`target`], sub-pixel saddle points in [`saddle`]), wide-angle intrinsics with outlier rejection ([`intrinsics`]),
//! stereo calibration at home ([`stereo`]), camera poses relative to home by bundle adjustment
//! over every corner of every board, written as calibration datasets ([`measure`]), and a
//! renderer of AprilGrid sessions with ground truth ([`render_grid`]).
pub mod apriltag3;
pub mod detect;
pub mod error;
pub mod intrinsics;
pub mod measure;
pub mod render_grid;
pub mod saddle;
pub mod session;
pub mod stereo;
pub mod target;

pub use error::{CamcalError, Result};
