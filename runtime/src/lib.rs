//! # abvs-runtime: the perception runtime
//!
//! Grouped by role, data flowing one way: **sources** (frames, encoders) -> **tasks** (time alignment,
//! per-eye FK and the moving extrinsic, rectification, disparity, depth and cloud) -> **sinks** (stats,
//! truth scoring, dumps, MCAP recordings) and **bridges** (iceoryx2 and Zenoh publishing to other processes); [`ros2`]
//! builds the ROS 2 messages of a frame. The roles share [`messages`] (and its clock); every task is a
//! [`stage::Stage`]; [`runner`] runs any graph of them on threads joined by bounded channels, and
//! [`pipeline`] declares the standard one. [`session`] is the on-disk format of recorded sessions, which
//! [`record`] writes from live sources.
#![warn(missing_docs)]
pub mod bridges;
pub mod config;
pub mod error;
pub mod messages;
pub mod outputs;
pub mod pipeline;
pub mod record;
pub mod ros2;
pub mod runner;
pub mod runtime;
pub mod session;
pub mod shipped;
pub mod sinks;
pub mod sources;
pub mod stage;
pub mod stats;
pub mod tasks;

pub use error::{Result, RuntimeError};
pub use runtime::{Report, Runtime, RuntimeHandle};
