//! Why a self-check log cannot be analysed.
use std::path::PathBuf;

use abvs_runtime::sinks::self_check::log_record::LogError;

/// What went wrong, naming the file (and the line or frame where there is one).
#[derive(Debug, thiserror::Error)]
pub enum SelfCheckError {
    /// A log that cannot be read or does not follow its record kind.
    #[error(transparent)]
    Log(#[from] LogError),
    /// A file beside the log (its run's configuration) that cannot be read.
    #[error("reading {}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// What the system said.
        #[source]
        source: std::io::Error,
    },
    /// A log whose rows carry two run identities.
    #[error("{}: rows of two runs ({first} and {second}): one log, one run", path.display())]
    MixedRuns {
        /// The log.
        path: PathBuf,
        /// The first run seen.
        first: u64,
        /// Another.
        second: u64,
    },
    /// A match log of another run than its frame log.
    #[error(
        "{} is of run {match_run}, the frame log {} of run {frame_run}: logs of different runs (each `abvs run \
         --self-check-log` writes both; keep them together)",
        match_log.display(),
        frame_log.display()
    )]
    DifferentRuns {
        /// The match log.
        match_log: PathBuf,
        /// Its run.
        match_run: u64,
        /// The frame log.
        frame_log: PathBuf,
        /// Its run.
        frame_run: u64,
    },
    /// A run configuration whose run line does not hold a number.
    #[error("{}: run_id `{value}` is not a number", path.display())]
    RunIdNotANumber {
        /// The configuration.
        path: PathBuf,
        /// The value found.
        value: String,
    },
    /// A frame log without the timing columns where they are required.
    #[error("{}: no timing columns", path.display())]
    NoTimingColumns {
        /// The log.
        path: PathBuf,
    },
    /// A frame whose timing fields are not numbers.
    #[error("{}:{line}: timing fields (seq, speeds, readout, offsets) must be numbers", path.display())]
    TimingNotNumbers {
        /// The log.
        path: PathBuf,
        /// The line.
        line: u64,
    },
    /// A log whose applied timing changed from frame to frame.
    #[error(
        "frame {seq}: the log's timing changed during the run (readout {readout_ms} ms, offsets {offset_ms:?} ms; \
         first frame: {first_readout_ms} ms, {first_offset_ms:?} ms): one log, one timing"
    )]
    TimingChanged {
        /// The first frame that differs.
        seq: u64,
        /// Its readout (ms).
        readout_ms: f64,
        /// Its offsets (ms).
        offset_ms: [f64; 2],
        /// The first frame's readout (ms).
        first_readout_ms: f64,
        /// The first frame's offsets (ms).
        first_offset_ms: [f64; 2],
    },
    /// A match of a frame the frame log does not have.
    #[error("match log: frame {seq} is not in the frame log (logs of different runs?)")]
    MatchWithoutFrame {
        /// The match's frame.
        seq: u64,
    },
    /// Too few frames with a rotation error to analyse.
    #[error("{}: {frames} frames with a rotation error; at least 3 are needed", path.display())]
    TooFewFrames {
        /// The log.
        path: PathBuf,
        /// Frames with a rotation error.
        frames: usize,
    },
    /// The nominal forward kinematics (the gaze of each logged frame).
    #[error(transparent)]
    Kinematics(#[from] abvs_eye::EyeError),
    /// A replay round of the runtime.
    #[error(transparent)]
    Runtime(#[from] abvs_runtime_core::error::RuntimeError),
}

/// The crate's result.
pub type Result<T> = std::result::Result<T, SelfCheckError>;
