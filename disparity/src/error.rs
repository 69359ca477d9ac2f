//! The disparity crate's error type: every refusal names the file or engine and keeps its cause.
use std::path::PathBuf;

/// Why a disparity engine, model or file was refused.
#[derive(Debug, thiserror::Error)]
pub enum DisparityError {
    /// A model (directory, manifest, ONNX file) the engines cannot use.
    #[error("{}: {msg}", path.display())]
    Model {
        /// The file or directory.
        path: PathBuf,
        /// What is wrong.
        msg: String,
    },
    /// A data file (a PFM, a ground truth, an image) that does not follow its format.
    #[error("{}: {msg}", path.display())]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        msg: String,
    },
    /// A file that cannot be read.
    #[error("{}: {source}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// A file that cannot be written.
    #[error("writing {}: {source}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// A manifest.json that is not a disparity model's manifest.
    #[error("{}: bad manifest: {source}", path.display())]
    Manifest {
        /// The manifest.
        path: PathBuf,
        /// The cause.
        #[source]
        source: serde_json::Error,
    },
    /// ONNX Runtime refused the model or a tensor of it.
    #[error("{}: {source}", path.display())]
    Onnx {
        /// The ONNX file.
        path: PathBuf,
        /// The cause.
        #[source]
        source: ort::Error,
    },
    /// ONNX Runtime itself could not be loaded, or could not open the model.
    #[error("{}: {source}", path.display())]
    OnnxRuntime {
        /// The ONNX file.
        path: PathBuf,
        /// The cause.
        #[source]
        source: abvs_onnx::OnnxError,
    },
    /// The model file's SHA-256 could not be checked.
    #[error("{}: {source}", path.display())]
    Hash {
        /// The model file.
        path: PathBuf,
        /// The cause.
        #[source]
        source: abvs_fk::FkError,
    },
    /// OpenCV failed inside an engine (`what`: the engine or the call).
    #[error("invalid: {what}: {}", source.message)]
    OpenCv {
        /// The engine or the call.
        what: &'static str,
        /// The cause.
        #[source]
        source: opencv::Error,
    },
    /// A value or a combination the engines cannot work with (sizes, ranges, an engine's name).
    #[error("invalid: {0}")]
    Invalid(String),
}

/// The disparity crate's result type.
pub type Result<T> = std::result::Result<T, DisparityError>;

/// An OpenCV error inside `what` (an engine's name or the call).
pub(crate) fn cv(what: &'static str) -> impl Fn(opencv::Error) -> DisparityError {
    move |source| DisparityError::OpenCv { what, source }
}
