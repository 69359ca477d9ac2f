//! Bridges: publishing to other processes (iceoryx2 shared memory).
pub mod iceoryx;
pub mod publish;
