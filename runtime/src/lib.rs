//! # abvs-runtime: the perception runtime
//!
//! Depth, its confidence and point clouds from a humanoid robot's moving eyes, in the robot's own process.
//! One call assembles a deployment from its configuration ([`config::RuntimeConfig`]: the file `abvs run
//! --config` takes, or built in code): [`Runtime::from_config`] opens the source (a recorded session, or the
//! eye cameras and the drive board), loads the calibration and the FK models, builds the disparity engine and
//! opens the sinks and bridges the configuration names. The `abvs` program is that call plus its flags.
//!
//! ## Embedding it
//!
//! `runtime/examples/embed.rs` (run by the tests, as `cargo run -p abvs-runtime --example embed`): the
//! fixture session at 320x240 on a thread of its own, its counts read while it runs, its report at the end.
//!
#![doc = concat!("```rust,ignore\n", include_str!("../examples/embed.rs"), "```")]
//!
//! Frames reach code of one's own two ways:
//!
//! - **in this process**, a [`sinks::Sink`] added with [`Runtime::add_sink`] receives every published frame
//!   ([`messages::Published`]: depth, cloud, poses, the rectified pair) on the output lane:
//!   `runtime/examples/custom_sink.rs`;
//! - **in another process** on this computer, [`bridges::iceoryx::Subscriber`] receives the depth maps, their
//!   confidence and the clouds from shared memory with their typed header ([`bridges::iceoryx::FrameHeader`],
//!   the layout the Python module reads), opened with the deployment's [`config::RuntimeConfig::bridge_config`]:
//!   `runtime/examples/subscribe.rs`. Other computers get the ROS 2 messages over Zenoh ([`bridges::zenoh`]).
//!
//! ## The parts
//!
//! Grouped by role, data flowing one way: **sources** (frames, encoders) -> **tasks** (time alignment,
//! per-eye FK and the moving extrinsic, rectification, disparity, depth and cloud) -> **sinks** (stats,
//! dumps, the self-check, MCAP recordings) and **bridges** (iceoryx2 and Zenoh publishing to other
//! processes); [`ros2`] builds the ROS 2 messages of a frame. The roles share [`messages`] (and its clock);
//! every task is a [`stage::Stage`]; [`runner`] runs any graph of them on threads joined by bounded channels,
//! and [`pipeline`] declares the standard one, which [`runtime`] assembles from a configuration. [`session`]
//! is the on-disk format of recorded sessions, which [`record`] writes from live sources. [`gaze`] points the
//! eyes: goals from the robot's processes ([`gaze::GazeHandle`], [`RuntimeHandle::gaze`]) become moves of the
//! drive board, on the port the live source reads.
#![warn(missing_docs)]
pub mod bridges;
pub mod config;
pub mod cpu;
pub mod error;
pub mod gaze;
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
pub use runtime::{CustomSource, Report, Runtime, RuntimeHandle};
