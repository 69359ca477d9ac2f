//! Analysis of the runtime's self-check logs (`abvs run --self-check-log FILE`), as a library: what
//! `abvs calib self-check` reports, returned as typed values so that a robot process or a notebook can ask
//! the same questions without parsing a report.
//!
//! - [`attribution`]: where in the workspace the stereo rotation error is and which eye's model it follows
//!   ([`attribution::Verdict`] names the eye; [`eye_fit`] compares the eyes' FK models, [`f_test`] its tail);
//! - [`timing_log`] and [`timing_fit`]: the eyes' encoder-to-camera offsets and the rolling-shutter readout
//!   fitted to the logged matches;
//! - [`rounds`]: the fit repeated on replays of the logged session with each estimate applied.
//!
//! The logs' records are the runtime's (`abvs_runtime::sinks::self_check::log_record`), so the writer and
//! these readers name every column in one place. This crate is toolkit side: the runtime does not depend on it.
#![warn(missing_docs)]

pub mod attribution;
pub mod error;
pub mod eye_fit;
pub mod f_test;
pub mod rounds;
pub mod timing_fit;
pub mod timing_log;
