//! A stand-in camera for the live-head tests (gaze_live, gaze_access): one picture, delivered in real time.
use std::time::Duration;

use abvs_runtime::sources::v4l_capture::{CaptureError, FrameSource};
use abvs_runtime_core::messages::monotonic_ns;
use abvs_runtime_core::messages::Frame;

pub const PERIOD_NS: i64 = 40_000_000;
pub const EXPOSURE_NS: i64 = 8_000_000;
pub const READOUT_NS: i64 = 20_000_000;

/// A camera showing one picture, a frame every 40 ms of CLOCK_MONOTONIC, delivered when its last row is read.
pub struct StillCamera {
    pub pixels: Vec<u8>,
    pub width: u32,
    pub height: u32,
    pub next: u64,
    pub n: u64,
    pub t0: i64,
}

impl FrameSource for StillCamera {
    fn next_frame(&mut self, mut gray: Vec<u8>) -> Result<Frame, CaptureError> {
        if self.next >= self.n {
            std::thread::sleep(Duration::from_millis(20));
            return Err(CaptureError::Timeout { path: "still".into() });
        }
        let t_start = self.t0 + self.next as i64 * PERIOD_NS;
        let wait = t_start + READOUT_NS + EXPOSURE_NS - monotonic_ns();
        if wait > 0 {
            std::thread::sleep(Duration::from_nanos(wait as u64));
        }
        gray.clear();
        gray.extend_from_slice(&self.pixels);
        self.next += 1;
        Ok(Frame {
            seq: self.next - 1,
            t_start_ns: t_start,
            exposure_ns: EXPOSURE_NS,
            readout_anchor: 0.0,
            width: self.width,
            height: self.height,
            gray,
        })
    }

    fn frame_len(&self) -> usize {
        (self.width * self.height) as usize
    }
}
