//! The paper crate's error type: what calibration, the unit files and the plots refuse, with
//! their sources, plus the report's own configuration and file errors.
use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum PaperError {
    #[error(transparent)]
    Calib(#[from] abvs_calib::CalibError),
    #[error(transparent)]
    Eye(#[from] abvs_eye::EyeError),
    #[error(transparent)]
    Plot(#[from] abvs_plot::PlotError),
    /// A [`crate::PaperConfig`] that cannot run (grids, sizes, units).
    #[error("paper config: {0}")]
    Config(String),
    /// Simulated data without what the experiments need (commanded poses, a PSC split).
    #[error("data: {0}")]
    Data(String),
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

pub type Result<T> = std::result::Result<T, PaperError>;

impl PaperError {
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        PaperError::Io { path: path.into(), source }
    }
}
