//! The error type of FK models and their calibration (abvs-calib uses it as `CalibError`).
use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum FkError {
    #[error(transparent)]
    Eye(#[from] abvs_eye::EyeError),
    #[error(transparent)]
    Onnx(#[from] abvs_onnx::OnnxError),
    /// Training / fitting data unusable (too few samples, NaN, ...).
    #[error("data: {0}")]
    Data(String),
    /// A model directory, manifest or network file is missing or malformed.
    #[error("model {}: {msg}", path.display())]
    Model { path: PathBuf, msg: String },
    /// Model and data do not fit together (wrong inputs/outputs, other unit, ...).
    #[error("mismatch: {0}")]
    Mismatch(String),
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A network file that is valid ONNX but not a plain MLP graph (run it through ONNX Runtime).
    #[error("model {}: not a plain MLP graph: {reason}", path.display())]
    NotMlp { path: PathBuf, reason: String },
    #[error("invalid argument: {0}")]
    Invalid(String),
    /// Calibrated IK refused a target: unreachable, near-singular, or no convergence.
    #[error("target [{:.4}, {:.4}, {:.4}] deg refused: {why}", target_deg[0], target_deg[1], target_deg[2])]
    Unreachable { target_deg: [f64; 3], why: String },
}

pub type Result<T> = std::result::Result<T, FkError>;

impl FkError {
    pub fn model(path: impl Into<PathBuf>, msg: impl Into<String>) -> Self {
        FkError::Model { path: path.into(), msg: msg.into() }
    }
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        FkError::Io { path: path.into(), source }
    }
}
