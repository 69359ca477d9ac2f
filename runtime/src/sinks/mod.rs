//! Sinks (implementations of [`abvs_runtime_core::sink::Sink`]): where results leave the pipeline inside this process (latency statistics, PNG
//! dumps, recorded sessions, MCAP recordings of the ROS 2 messages). Ground-truth scoring of synthetic sessions is offline: abvs-sim.
pub mod dump;
#[cfg(feature = "mcap")]
pub mod mcap_log;
#[cfg(feature = "rerun")]
pub mod rerun_log;
pub mod ros2_out;
pub mod self_check;
pub mod session_writer;
pub mod side_lane;
