//! The eye devices as `[source.live]` describes them ([`LiveConfig`]): the drive board's encoder port and the
//! two cameras opened, the encoder thread started, both eyes homed. `abvs record` and a live [`crate::Runtime`]
//! open them the same way.
use std::time::{Duration, Instant};

use crate::sources::pairing::PairerConfig;
use crate::sources::v4l_capture::{CaptureConfig, RowReference, StereoCapture};
use abvs_board::port::open_port;
use abvs_board::stream::EncoderStream;
use abvs_runtime_core::config::LiveConfig;
use abvs_runtime_core::error::{Result, RuntimeError};

/// Encoder rows the stream's channel holds for a consumer that falls behind.
const ENCODER_QUEUE: usize = 16_384;

/// Opens the encoder port, then both cameras (in that order: a missing port is the cheaper mistake), and
/// starts the encoder thread.
pub fn open_devices(l: &LiveConfig) -> Result<(StereoCapture, EncoderStream)> {
    let cfg = capture_config(l)?;
    let pairing = PairerConfig { tolerance_ns: (l.pair_tolerance_ms * 1e6).round() as i64, ..Default::default() };
    let port = open_port(&l.encoders, l.baud).map_err(|e| RuntimeError::Device(e.to_string()))?;
    let capture =
        StereoCapture::open(&l.left, &l.right, cfg, pairing).map_err(|e| RuntimeError::Device(e.to_string()))?;
    // the same port carries the gaze controller's commands to the board
    let writer =
        port.try_clone().map_err(|e| RuntimeError::Device(format!("{}: cannot clone the port: {e}", l.encoders)))?;
    let stream = EncoderStream::spawn(port, l.encoders.clone(), ENCODER_QUEUE);
    Ok((capture, stream.with_commands(Box::new(writer), l.encoders.clone())))
}

/// What the cameras are asked for: size, pixel format, rate, exposure, the rolling-shutter readout (frames
/// stamped at their first row).
pub fn capture_config(l: &LiveConfig) -> Result<CaptureConfig> {
    let fourcc: [u8; 4] = l
        .fourcc
        .as_bytes()
        .try_into()
        .map_err(|_| RuntimeError::Invalid(format!("source.live.fourcc `{}`: four characters", l.fourcc)))?;
    Ok(CaptureConfig {
        width: l.width,
        height: l.height,
        fourcc,
        fps: l.fps,
        exposure_ns: l.exposure_ms.map(|ms| (ms * 1e6).round() as i64),
        readout_ns: (l.readout_ms * 1e6).round() as i64,
        reference: RowReference::FirstRow,
        ..CaptureConfig::default()
    })
}

/// Waits until the drive board's stream has homed both eyes (their links roll through the index markers at
/// start-up), or fails naming the eye and the last refusal.
pub fn wait_for_homing(encoders: &EncoderStream, timeout_s: f64) -> Result<()> {
    let t0 = Instant::now();
    while encoders.homed() != [true, true] {
        if encoders.is_finished() {
            return Err(RuntimeError::Device("the encoder stream ended before homing".into()));
        }
        if t0.elapsed().as_secs_f64() > timeout_s {
            let s = encoders.stats();
            return Err(RuntimeError::Device(format!(
                "eyes not homed within {timeout_s:.0} s (homed {:?}; samples {:?}; last refusals {:?})",
                encoders.homed(),
                s.homing_samples,
                s.last_homing_error
            )));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    Ok(())
}
