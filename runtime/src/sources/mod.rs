//! Sources: where data enters the runtime (cameras, the encoder board, recorded sessions).
pub mod encoder_link;
pub mod encoder_stream;
pub mod live;
pub mod pairing;
pub mod pixel;
pub mod replay;
pub mod v4l_capture;

/// One grayscale camera frame as it leaves a source: 8-bit luma, row-major, tightly packed.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// Source sequence number (V4L2 buffer sequence, or the recorded index).
    pub seq: u64,
    /// Start of exposure, CLOCK_MONOTONIC, nanoseconds.
    pub t_start_ns: i64,
    /// Exposure time, nanoseconds (mid-exposure = t_start_ns + exposure_ns / 2).
    pub exposure_ns: i64,
    pub width: u32,
    pub height: u32,
    pub gray: Vec<u8>,
}

impl Frame {
    /// Mid-exposure time (CLOCK_MONOTONIC ns): the instant the encoders are interpolated to.
    pub fn t_mid_ns(&self) -> i64 {
        self.t_start_ns + self.exposure_ns / 2
    }
}

/// A left/right pair of frames taken together.
#[derive(Clone, Debug, PartialEq)]
pub struct FramePair {
    /// Pair sequence number (increases by one per pair delivered).
    pub seq: u64,
    pub left: Frame,
    pub right: Frame,
}
