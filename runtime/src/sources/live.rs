//! The live source of the pipeline: the two eye cameras ([`StereoCapture`]) and the drive board's
//! encoder stream ([`EncoderStream`], homed, on CLOCK_MONOTONIC), and the board's command side on the same
//! port ([`PairSource::board`]: the gaze controller's moves). Frames come when the cameras
//! deliver them (no pacing); the time-alignment stage waits briefly for encoder samples still on
//! the wire.
use std::time::{Duration, Instant};

use abvs_board::stream::EncoderStream;
use abvs_board::tracker::HomedSample;

use crate::sources::v4l_capture::{CaptureError, StereoCapture};
use abvs_runtime_core::messages::FramePair;
use abvs_runtime_core::messages::{EncoderSample, SourcePair};
use abvs_runtime_core::source::{EncoderFeed, PairSource};
use abvs_runtime_core::stats::RunStats;

/// How long the time-alignment stage waits for encoder samples that should exist by now.
pub const ENCODER_WAIT: Duration = Duration::from_millis(30);

/// The eye cameras and the drive board as a [`PairSource`].
pub struct LiveSource {
    capture: StereoCapture,
    encoders: Option<EncoderStream>,
    width: u32,
    height: u32,
    /// The pair handed out last (its buffers go back to the capture on the next call).
    current: Option<FramePair>,
    emitted: u64,
    pair_timeout: Duration,
    /// Why the capture ended, if it did.
    pub ended: Option<String>,
    /// Pairs of another size than the pipeline's (dropped).
    pub wrong_size: u64,
    /// The sensors' rolling-shutter readout (ns): every pair carries it to the per-row correction.
    readout_ns: i64,
}

impl LiveSource {
    /// `width` x `height`: the size the cameras were opened with (they refuse another one).
    pub fn new(capture: StereoCapture, encoders: EncoderStream, width: u32, height: u32) -> LiveSource {
        LiveSource {
            capture,
            encoders: Some(encoders),
            width,
            height,
            current: None,
            emitted: 0,
            pair_timeout: Duration::from_secs(2),
            readout_ns: 0,
            ended: None,
            wrong_size: 0,
        }
    }

    /// Opens the devices `[source.live]` describes ([`crate::sources::devices`]) and waits until both eyes are
    /// homed.
    pub fn open(l: &abvs_runtime_core::config::LiveConfig) -> abvs_runtime_core::error::Result<LiveSource> {
        let (capture, encoders) = crate::sources::devices::open_devices(l)?;
        crate::sources::devices::wait_for_homing(&encoders, l.homing_timeout_s)?;
        Ok(LiveSource::new(capture, encoders, l.width, l.height))
    }

    /// The cameras' rolling-shutter readout (ns, `CaptureConfig::readout_ns`; frames' `t_start_ns` must be
    /// their first row's, `RowReference::FirstRow`): the runtime corrects each row with the eye's pose then.
    pub fn with_readout_ns(mut self, readout_ns: i64) -> LiveSource {
        self.readout_ns = readout_ns.max(0);
        self
    }
}

impl PairSource for LiveSource {
    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    fn board(&mut self) -> Option<Box<dyn abvs_runtime_core::source::BoardLink>> {
        let board = self.encoders.as_mut()?.take_commands()?;
        Some(Box::new(crate::sources::board::SerialBoard(board)))
    }

    fn start(&mut self, _now_ns: i64) -> Box<dyn EncoderFeed> {
        let stream = self.encoders.take().expect("a live source starts once");
        Box::new(LiveEncoders { stream, newest_ns: [i64::MIN; 2] })
    }

    fn next_frame(&mut self, limit: Option<u64>) -> Option<SourcePair<'_>> {
        if let Some(p) = self.current.take() {
            self.capture.recycle(p);
        }
        if limit.is_some_and(|n| self.emitted >= n) {
            return None;
        }
        loop {
            match self.capture.next_pair(self.pair_timeout) {
                Ok(p) if (p.left.width, p.left.height) != (self.width, self.height) => {
                    self.wrong_size += 1;
                    self.capture.recycle(p);
                }
                Ok(p) => {
                    self.current = Some(p);
                    break;
                }
                Err(e) => {
                    self.ended = Some(match e {
                        CaptureError::Timeout { .. } => {
                            format!("no stereo pair for {:.1} s", self.pair_timeout.as_secs_f64())
                        }
                        e => e.to_string(),
                    });
                    return None;
                }
            }
        }
        self.emitted += 1;
        let p = self.current.as_ref().expect("just stored");
        Some(SourcePair {
            // the camera's own frame number (a stand-in camera replaying a session puts the
            // session seq there, which lets ground truth be looked up)
            session_seq: p.left.seq,
            seq: p.seq,
            t_start_ns: p.left.t_start_ns,
            right_t_start_ns: p.right.t_start_ns,
            exposure_ns: p.left.exposure_ns,
            readout_ns: self.readout_ns,
            readout_anchor: p.left.readout_anchor,
            left: &p.left.gray,
            right: &p.right.gray,
        })
    }

    fn finish(&mut self, stats: &mut RunStats) {
        let c = self.capture.stats();
        stats.extra.insert("capture".into(), serde_json::to_value(c).unwrap_or_default());
        stats.extra.insert("capture_wrong_size".into(), serde_json::json!(self.wrong_size));
        if let Some(e) = &self.ended {
            stats.extra.insert("capture_ended".into(), serde_json::json!(e));
        }
    }
}

/// The encoder stream as the pipeline's [`EncoderFeed`].
struct LiveEncoders {
    stream: EncoderStream,
    newest_ns: [i64; 2],
}

impl LiveEncoders {
    fn push(&mut self, h: HomedSample, push: &mut dyn FnMut(usize, EncoderSample)) {
        let r = encoder_record(&h);
        let s = r.sample();
        let eye = usize::from(r.eye.min(1));
        self.newest_ns[eye] = self.newest_ns[eye].max(r.t_ns);
        push(eye, EncoderSample { t_s: s.t_s, theta_deg: s.theta_deg });
    }
}

impl EncoderFeed for LiveEncoders {
    fn feed(&mut self, t_ns: i64, push: &mut dyn FnMut(usize, EncoderSample)) {
        while let Ok(r) = self.stream.records().try_recv() {
            self.push(r, push);
        }
        // Samples up to t_ns may still be in the serial link: wait for them a little.
        let deadline = Instant::now() + ENCODER_WAIT;
        while self.newest_ns.iter().any(|&n| n < t_ns) {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.stream.records().recv_timeout(left) {
                Ok(r) => self.push(r, push),
                Err(_) => break,
            }
        }
    }
}

/// A homed sample of the board link as a row of a session's encoders.csv.
pub(crate) fn encoder_record(h: &HomedSample) -> abvs_runtime_core::session::EncoderRecord {
    let [count1, count2, count3] = h.counts;
    abvs_runtime_core::session::EncoderRecord { t_ns: h.t_ns, eye: h.eye, count1, count2, count3 }
}
