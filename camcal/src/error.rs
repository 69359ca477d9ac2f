//! The one error type of abvs-camcal.
use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum CamcalError {
    #[error("{}: cannot read image ({msg})", path.display())]
    ImageRead { path: PathBuf, msg: String },
    #[error("{}: {msg}", path.display())]
    File { path: PathBuf, msg: String },
    #[error("invalid: {0}")]
    Invalid(String),
    #[error("calibration failed: {0}")]
    Calibration(String),
    #[error("opencv: {0}")]
    OpenCv(#[from] opencv::Error),
    #[error(transparent)]
    Io(#[from] std::io::Error),
    #[error(transparent)]
    Eye(#[from] abvs_eye::EyeError),
}

pub type Result<T> = std::result::Result<T, CamcalError>;
