//! # abvs-camera: camera models and calibration files
//!
//! One camera model for the whole project (renderer, calibration from images, rectification in the runtime):
//! OpenCV's pinhole family and fisheye, with OpenCV's formulas and coefficient orders ([`model`]), and the
//! OpenCV FileStorage YAML files for one camera and for the stereo pair at home ([`yaml`]).
pub mod model;
pub mod yaml;

pub use model::{Camera, Distortion};
pub use yaml::{CalibInfo, CameraError, StereoCalibration};
