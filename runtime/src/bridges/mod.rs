//! Bridges: publishing to other processes (iceoryx2 shared memory on this computer, ROS 2 messages
//! over Zenoh to others).
pub mod iceoryx;
pub mod publish;
#[cfg(feature = "zenoh")]
pub mod rmw_zenoh;
#[cfg(feature = "zenoh")]
pub mod zenoh;
#[cfg(feature = "zenoh")]
pub mod zenoh_gaze;
#[cfg(feature = "zenoh")]
pub mod zenoh_shm;
