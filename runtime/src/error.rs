//! The runtime's error type: every refusal says which stream and what was wrong.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum RuntimeError {
    /// A sample older than or equal to the previous one in a stream that must increase.
    #[error("{stream}: timestamp {t:.6} s is not after the previous {prev:.6} s")]
    NonMonotonic { stream: &'static str, t: f64, prev: f64 },
    /// A query outside the span the buffer holds (frame too old, or encoders not caught up).
    #[error("{stream}: time {t:.6} s is outside the buffered span [{from:.6}, {to:.6}] s")]
    OutOfSpan { stream: &'static str, t: f64, from: f64, to: f64 },
    /// A gap in the encoder stream too long to interpolate across.
    #[error("{stream}: gap of {gap_ms:.2} ms around {t:.6} s exceeds {max_ms:.2} ms")]
    Gap { stream: &'static str, t: f64, gap_ms: f64, max_ms: f64 },
    #[error("invalid: {0}")]
    Invalid(String),
    /// A file that cannot be read or does not follow its format; `line` when the fault has one.
    #[error("{}{}: {msg}", path.display(), line.map(|l| format!(":{l}")).unwrap_or_default())]
    File { path: std::path::PathBuf, line: Option<u64>, msg: String },
    /// A calibration or model file the pipeline cannot use.
    #[error("{}: {msg}", path.display())]
    Model { path: std::path::PathBuf, msg: String },
    /// An output the run would write (a file, a directory) that it cannot: checked before any work, so a
    /// long run does not end by losing its results. `field` is the flag or configuration field.
    #[error("{field} {}: {msg}", path.display())]
    Output { field: String, path: std::path::PathBuf, msg: String },
    /// A device (a camera, the encoder port) that cannot be opened, or eyes that do not home.
    #[error("{0}")]
    Device(String),
    /// A stage failed on one frame (the pipeline counts it and goes on).
    #[error("frame {seq}: {stage}: {msg}")]
    Frame { seq: u64, stage: &'static str, msg: String },
}

pub type Result<T> = std::result::Result<T, RuntimeError>;
