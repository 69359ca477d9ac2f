//! The drive board link, onboard side (the runtime links it; no toolkit crate):
//!
//! - [`protocol`]: the versioned wire format, encoder frames (board -> host) and move commands
//!   (host -> board);
//! - [`decoder`]: byte streams -> frames, resynchronising after garbage and counting what was lost;
//! - [`clock`]: board time -> CLOCK_MONOTONIC;
//! - [`tracker`]: decoding, per-eye homing and clock mapping together: bytes -> homed, stamped samples;
//! - [`stream`]: the tracker on a thread over a port; [`commands`]: moves written on the same port;
//! - [`saccade`]: yoked moves run and measured on the board's own stream;
//! - [`port`]: opening the serial port. [`error`]: what fails.
//!
//! The simulated board that answers this protocol is the simulator's (`abvs_sim::board_server`).
#![warn(missing_docs)]

pub mod clock;
pub mod commands;
pub mod decoder;
pub mod error;
pub mod port;
pub mod protocol;
pub mod saccade;
pub mod stream;
pub mod tracker;
pub mod watch;
