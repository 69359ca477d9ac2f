//! # abvs-runtime: the perception runtime
//!
//! Depth, its confidence and point clouds from a humanoid robot's moving eyes, in the robot's own process.
//! One call assembles a deployment from its configuration ([`abvs_runtime_core::config::RuntimeConfig`]: the file `abvs run
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
//! - **in this process**, an [`abvs_runtime_core::sink::Sink`] added with [`Runtime::add_sink`] receives every
//!   published frame ([`abvs_runtime_core::messages::Published`]: depth, cloud, poses, the rectified pair) on the output lane:
//!   `runtime/examples/custom_sink.rs`;
//! - **in another process** on this computer, [`bridges::iceoryx::Subscriber`] receives the depth maps, their
//!   confidence and the clouds from shared memory with their typed header ([`bridges::iceoryx::FrameHeader`],
//!   the layout the Python module reads), opened with the deployment's [`bridges::iceoryx::BridgeConfig::for_deployment`]:
//!   `runtime/examples/subscribe.rs`. Other computers get the ROS 2 messages over Zenoh ([`bridges::zenoh`]).
//!
//! ## The parts
//!
//! Grouped by role, data flowing one way: **sources** (frames, encoders) -> **tasks** (time alignment,
//! per-eye FK and the moving extrinsic, rectification, disparity, depth and cloud) -> **sinks** (stats,
//! dumps, the self-check, MCAP recordings) and **bridges** (iceoryx2 and Zenoh publishing to other
//! processes); [`ros2`] builds the ROS 2 messages of a frame. The roles share the bottom crate,
//! [`abvs_runtime_core`]: its messages (and the clock), its contracts (every task is an
//! [`abvs_runtime_core::stage::Stage`]), errors, statistics, configuration and session format; [`runner`] runs any graph of them on threads joined by bounded channels,
//! and [`pipeline`] declares the standard one, which [`Runtime`] assembles from a configuration. [`record`]
//! writes recorded sessions ([`abvs_runtime_core::session`]) from live sources. [`gaze`] points the
//! eyes: goals from the robot's processes ([`gaze::GazeHandle`], [`RuntimeHandle::gaze`]) become moves of the
//! drive board, on the port the live source reads.
#![warn(missing_docs)]
pub mod bridges;
pub mod gaze;
pub mod outputs;
pub mod pipeline;
pub mod record;
pub mod ros2;
pub mod runner;
mod runtime;
pub mod shipped;
pub mod sinks;
pub mod sources;
pub mod tasks;

pub use runtime::{CustomSource, Overload, Report, Runtime, RuntimeHandle};
