//! The crate's one error type: every failure names what was asked and why it was refused.
use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum EyeError {
    /// A pose or link configuration has no solution on the working-mode branch.
    #[error("unreachable: {0}")]
    Unreachable(String),
    /// The configuration is too close to a singularity to be trusted.
    #[error("near singularity: {what} (measure {measure:.4} < limit {limit:.4})")]
    NearSingular { what: String, measure: f64, limit: f64 },
    /// Newton did not converge (or left the working mode).
    #[error("forward kinematics failed: {0}")]
    FkFailed(String),
    /// Encoder homing could not decide the absolute angles.
    #[error("homing: {0}")]
    Homing(String),
    /// A dataset or table file is malformed; line is 1-based (the header is line 1).
    #[error("{}{}: {msg}", path.display(), line.map(|l| format!(":{l}")).unwrap_or_default())]
    File { path: PathBuf, line: Option<usize>, msg: String },
    /// A unit-model file is malformed or holds an implausible value.
    #[error("unit model {}: {msg}", path.display())]
    Unit { path: PathBuf, msg: String },
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("invalid argument: {0}")]
    Invalid(String),
}

pub type Result<T> = std::result::Result<T, EyeError>;

impl EyeError {
    pub fn file(path: impl Into<PathBuf>, line: Option<usize>, msg: impl Into<String>) -> Self {
        EyeError::File { path: path.into(), line, msg: msg.into() }
    }
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        EyeError::Io { path: path.into(), source }
    }
}
