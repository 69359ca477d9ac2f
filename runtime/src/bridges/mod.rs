//! Bridges: publishing to other processes (iceoryx2 shared memory).
