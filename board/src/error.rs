//! Why the board link failed.

/// A failure of the drive board link, naming the port.
#[derive(Debug, thiserror::Error)]
pub enum BoardError {
    /// The serial port cannot be opened.
    #[error("encoder port {port}: {source}")]
    Open {
        /// The port's path.
        port: String,
        /// What the serial driver said.
        #[source]
        source: serialport::Error,
    },
    /// Reading the port failed.
    #[error("encoder port {port}: {source}")]
    Read {
        /// The port's path.
        port: String,
        /// What the system said.
        #[source]
        source: std::io::Error,
    },
    /// The port ended (a pseudo-terminal closed, a device unplugged).
    #[error("encoder port {port}: end of stream")]
    EndOfStream {
        /// The port's path.
        port: String,
    },
    /// Writing commands to the port failed.
    #[error("drive board {port}: {source}")]
    Write {
        /// The port's path.
        port: String,
        /// What the system said.
        #[source]
        source: std::io::Error,
    },
    /// A move before both eyes are homed (the board's raw counts have no known origin).
    #[error("drive board {port}: not homed")]
    NotHomed {
        /// The port's path.
        port: String,
    },
    /// A move target outside the board's raw count range (i32).
    #[error("drive board {port}: target counts out of range")]
    TargetOutOfRange {
        /// The port's path.
        port: String,
    },
    /// The eyes did not home and come to rest in time.
    #[error("{port}: both eyes not homed and at rest after {timeout_s:.1} s ({stats:?})")]
    NotAtRest {
        /// The port's path.
        port: String,
        /// How long it waited (s).
        timeout_s: f64,
        /// What the tracker saw.
        stats: Box<crate::tracker::EncoderStats>,
    },
    /// The reading thread panicked.
    #[error("encoder thread panicked")]
    ThreadPanicked,
}
