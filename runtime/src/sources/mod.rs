//! Sources: where data enters the runtime (cameras, the encoder board, recorded sessions).
pub mod board;
pub mod devices;
pub mod live;
pub mod pairing;
pub mod pixel;
pub mod replay;
pub mod v4l_capture;
