//! # abvs-runtime-core: the runtime's bottom layer
//!
//! What every part of the perception runtime shares, and nothing heavy (no OpenCV, ONNX Runtime, iceoryx2 or
//! Zenoh): a robot process, a toolkit or a test can implement a source, a stage or a sink against these
//! contracts without linking the engines.
//!
//! - [`messages`]: what flows between the roles (frames, encoder samples, poses, rectified pairs, depth, the
//!   pooled per-frame [`messages::Work`], the [`messages::Published`] frame sinks see) and the one clock
//!   ([`messages::monotonic_ns`]); [`gaze`]: the gaze's per-frame state, carried in the messages.
//! - The contracts: [`stage::Stage`] (every processing step), [`source::PairSource`] with its
//!   [`source::EncoderFeed`] (encoder samples handed through a callback) and [`source::BoardLink`] (the drive
//!   board's command side), [`sink::Sink`] (where finished frames go).
//! - [`error`]: [`error::RuntimeError`], the one error type of the runtime; [`stats`] and [`cpu`]: the run's
//!   statistics.
//! - [`config`]: the deployment file (`format = "abvs-runtime/1"`) as plain data with its defaults and checks;
//!   [`params`]: the settings each part runs with.
//! - [`lent`]: buffers a writer lends for one message, and the float map that can live in one.
//! - [`session`]: the on-disk format of recorded sessions, with the encoder time offset ([`session::TimeOffsetMs`]).
//!
//! The runtime (abvs-runtime) builds on it: the sources, the stages, the sinks and bridges, the runner.
#![warn(missing_docs)]
pub mod config;
pub mod cpu;
pub mod error;
pub mod gaze;
pub mod lent;
pub mod messages;
pub mod params;
pub mod session;
pub mod sink;
pub mod source;
pub mod stage;
pub mod stats;
