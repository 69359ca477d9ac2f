//! The runtime's error type: every refusal says which stream and what was wrong. A variant that wraps another
//! crate's error keeps it as its source (`std::error::Error::source`) and says it once in its message (the
//! program prints the chain without repeating a cause already said); the variants a caller may act on are
//! typed (a configuration refused, a feature not built, a thread that could not start or panicked).
#[derive(Debug, thiserror::Error)]
/// Why the runtime refused something: a stream, a file, a model, a frame.
pub enum RuntimeError {
    /// A sample older than or equal to the previous one in a stream that must increase.
    #[error("{stream}: timestamp {t:.6} s is not after the previous {prev:.6} s")]
    NonMonotonic {
        /// The stream.
        stream: &'static str,
        /// The sample's time (s).
        t: f64,
        /// The previous sample's time (s).
        prev: f64,
    },
    /// A query outside the span the buffer holds (frame too old, or encoders not caught up).
    #[error("{stream}: time {t:.6} s is outside the buffered span [{from:.6}, {to:.6}] s")]
    OutOfSpan {
        /// The stream.
        stream: &'static str,
        /// The time asked for (s).
        t: f64,
        /// The oldest time held (s).
        from: f64,
        /// The newest time held (s).
        to: f64,
    },
    /// A gap in the encoder stream too long to interpolate across.
    #[error("{stream}: gap of {gap_ms:.2} ms around {t:.6} s exceeds {max_ms:.2} ms")]
    Gap {
        /// The stream.
        stream: &'static str,
        /// The time asked for (s).
        t: f64,
        /// The gap around it (ms).
        gap_ms: f64,
        /// The longest gap interpolated across (ms).
        max_ms: f64,
    },
    /// The deployment's configuration is refused (a value, or a combination the source cannot run with).
    #[error("invalid: configuration: {0}")]
    Config(String),
    /// The configuration asks for something this build left out (a cargo feature of abvs-runtime).
    #[error("{field}: this build has no {feature} (abvs-runtime's cargo feature `{feature}`)")]
    NotBuilt {
        /// The configuration field that asks for it.
        field: &'static str,
        /// The cargo feature.
        feature: &'static str,
    },
    /// A thread of the runtime could not be started.
    #[error("invalid: {what}: {source}")]
    Thread {
        /// Which thread (and whose).
        what: String,
        /// Why the OS refused it.
        #[source]
        source: std::io::Error,
    },
    /// A thread of the runtime panicked (its work is lost).
    #[error("invalid: {0} panicked")]
    Panicked(String),
    /// An eye's FK model could not be compiled or evaluated.
    #[error("invalid: {0}")]
    Fk(#[source] Box<dyn std::error::Error + Send + Sync>),
    /// The iceoryx2 bridge failed (creating its services, publishing).
    #[error("invalid: {0}")]
    Ipc(#[source] Box<dyn std::error::Error + Send + Sync>),
    /// A transport of the ROS 2 messages failed (a Zenoh session, an MCAP file).
    #[error("invalid: {what}: {source}")]
    Transport {
        /// What was being done, naming the transport.
        what: String,
        /// The transport's error.
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// A camera frame could not be captured or decoded.
    #[error("invalid: {0}")]
    Capture(#[source] Box<dyn std::error::Error + Send + Sync>),
    /// A value or a combination the runtime cannot work with (a configuration, a graph, an argument).
    #[error("invalid: {0}")]
    Invalid(String),
    /// A file that cannot be read or does not follow its format; `line` when the fault has one.
    #[error("{}{}: {msg}", path.display(), line.map(|l| format!(":{l}")).unwrap_or_default())]
    File {
        /// The file.
        path: std::path::PathBuf,
        /// The line (1-based), when the fault has one.
        line: Option<u64>,
        /// What is wrong.
        msg: String,
    },
    /// A calibration or model file the pipeline cannot use.
    #[error("{}: {msg}", path.display())]
    Model {
        /// The file or directory.
        path: std::path::PathBuf,
        /// What is wrong.
        msg: String,
    },
    /// An output the run would write (a file, a directory) that it cannot: checked before any work, so a
    /// long run does not end by losing its results. `field` is the flag or configuration field.
    #[error("{field} {}: {msg}", path.display())]
    Output {
        /// The flag or configuration field that named the output.
        field: String,
        /// The output.
        path: std::path::PathBuf,
        /// What is wrong.
        msg: String,
    },
    /// A device (a camera, the encoder port) that cannot be opened, or eyes that do not home.
    #[error("{0}")]
    Device(String),
    /// A stage failed on one frame (the pipeline counts it and goes on).
    #[error("frame {seq}: {stage}: {msg}")]
    Frame {
        /// The frame's pipeline sequence number.
        seq: u64,
        /// The stage.
        stage: &'static str,
        /// What went wrong.
        msg: String,
    },
}

/// The runtime's result type.
pub type Result<T> = std::result::Result<T, RuntimeError>;
