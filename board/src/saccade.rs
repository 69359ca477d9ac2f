//! Yoked moves run and measured on the board's own stream (`abvs gaze saccade`): wait until both eyes are
//! homed and at rest, send both eyes' move commands together, watch the encoder frames until both eyes sit
//! at their targets, and time the move on the board's clock (without the host's scheduling).
//!
//! The plan (both eyes' minimum-jerk link moves sharing the slower eye's duration) is
//! `abvs_fk::gaze::YokedSaccade`; this module takes its target counts and duration.
use std::io::Write;
use std::time::{Duration, Instant};

use abvs_eye::encoder::counts_to_deg;

use crate::commands::move_commands;
use crate::decoder::{Decoder, LinkEvent};
use crate::error::BoardError;
use crate::port::open_port;
use crate::stream::monotonic_ns;
use crate::tracker::{EncoderStats, EncoderTracker, HomedSample};

/// Equal samples in a row that count as at rest (before the first move).
const AT_REST: usize = 50;
/// Samples in a row at the target that count as arrived.
const ARRIVED: usize = 10;

/// A homed sample on the board's clock.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Timed {
    /// The board's time of the frame (us).
    pub board_us: u64,
    /// Which eye: 0 left, 1 right.
    pub eye: usize,
    /// Homed counts.
    pub counts: [i64; 3],
}

impl Timed {
    /// The link angles (deg).
    pub fn deg(&self) -> [f64; 3] {
        self.counts.map(|c| counts_to_deg(c, 0))
    }
}

/// What one move did, measured on the encoder stream.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MoveMeasurement {
    /// From the first moving sample to the first sample at the target (board time, ms), per eye; 0 when the
    /// eye was already there, NaN when it did not arrive.
    pub measured_ms: [f64; 2],
    /// Largest link speed between consecutive samples (deg/s), per eye.
    pub peak_deg_s: [f64; 2],
    /// Both eyes sat at their targets for 10 samples before the timeout.
    pub arrived: bool,
}

/// The board's stream as a saccade reads it: the runtime's tracker (homing, clock mapping, homed samples:
/// what the runtime consumes) and, beside it, each frame's board time; commands on a clone of the port.
pub struct BoardSession {
    port: Box<dyn serialport::SerialPort>,
    writer: Box<dyn serialport::SerialPort>,
    name: String,
    tracker: EncoderTracker,
    frames: Decoder,
    samples: Vec<HomedSample>,
    homed_samples: u64,
    latest: [Option<Timed>; 2],
    seq: u16,
    buf: Vec<u8>,
}

impl BoardSession {
    /// Opens the board's port (1 Mbaud).
    pub fn open(name: &str) -> Result<BoardSession, BoardError> {
        let mut port = open_port(name, 1_000_000)?;
        let writer = port.try_clone().map_err(|source| BoardError::Open { port: name.to_string(), source })?;
        let _ = port.set_timeout(Duration::from_millis(20));
        Ok(BoardSession {
            port,
            writer,
            name: name.to_string(),
            tracker: EncoderTracker::new(),
            frames: Decoder::new(),
            samples: vec![],
            homed_samples: 0,
            latest: [None, None],
            seq: 0,
            buf: vec![0; 1 << 14],
        })
    }

    /// Reads what arrived: homed samples of frames after homing, on board time.
    fn poll(&mut self) -> Result<Vec<Timed>, BoardError> {
        let n = match std::io::Read::read(&mut self.port, &mut self.buf) {
            Ok(n) => n,
            Err(e) if matches!(e.kind(), std::io::ErrorKind::TimedOut | std::io::ErrorKind::WouldBlock) => 0,
            Err(source) => return Err(BoardError::Read { port: self.name.clone(), source }),
        };
        let bytes = &self.buf[..n];
        self.tracker.feed(bytes, monotonic_ns(), &mut self.samples);
        self.homed_samples += self.samples.len() as u64;
        self.samples.clear();
        let home = self.tracker.stats().home_counts;
        let mut out = vec![];
        for ev in self.frames.feed(bytes) {
            let f = match ev {
                LinkEvent::Frame(f) | LinkEvent::Reset(f) => f,
            };
            let eye = usize::from(f.eye);
            if let Some(Some(h)) = home.get(eye) {
                let counts = std::array::from_fn(|i| i64::from(f.counts[i]) - h[i]);
                out.push(Timed { board_us: f.board_time_us, eye, counts });
            }
        }
        Ok(out)
    }

    /// Waits until both eyes are homed (during the board's start-up roll) and their links rest (50 equal
    /// samples); both eyes' home counts.
    pub fn wait_homed_at_rest(&mut self, timeout: Duration) -> Result<[[i64; 3]; 2], BoardError> {
        let t_wait = Instant::now();
        let mut rest = [0usize; 2];
        while rest.iter().any(|&n| n < AT_REST) {
            for t in self.poll()? {
                let same = self.latest[t.eye].is_some_and(|p| p.counts == t.counts);
                rest[t.eye] = if same { rest[t.eye] + 1 } else { 0 };
                self.latest[t.eye] = Some(t);
            }
            if t_wait.elapsed() > timeout {
                return Err(BoardError::NotAtRest {
                    port: self.name.clone(),
                    timeout_s: timeout.as_secs_f64(),
                    stats: Box::new(self.tracker.stats()),
                });
            }
        }
        Ok(self.tracker.stats().home_counts.map(|h| h.expect("homed")))
    }

    /// The latest homed sample of each eye (after [`BoardSession::wait_homed_at_rest`]).
    pub fn latest(&self) -> [Timed; 2] {
        self.latest.map(|t| t.expect("a sample: wait_homed_at_rest first"))
    }

    /// Sends both eyes' move to `target_counts` (homed) over `duration_us` and watches the stream until both
    /// sit at their targets for 10 samples (board time) or `timeout` passes.
    pub fn execute(
        &mut self,
        home: [[i64; 3]; 2],
        target_counts: [[i64; 3]; 2],
        duration_us: u32,
        timeout: Duration,
    ) -> Result<MoveMeasurement, BoardError> {
        let bytes = move_commands(&mut self.seq, home, target_counts, duration_us, &self.name)?;
        self.writer
            .write_all(&bytes)
            .and_then(|_| self.writer.flush())
            .map_err(|source| BoardError::Write { port: self.name.clone(), source })?;
        let (mut moved_at, mut arrived_at) = ([None::<u64>; 2], [None::<u64>; 2]);
        let mut peak = [0.0f64; 2];
        let mut still = [0usize; 2];
        let start_counts = self.latest().map(|t| t.counts);
        let t_send = Instant::now();
        while still.iter().any(|&n| n < ARRIVED) && t_send.elapsed() < timeout {
            for t in self.poll()? {
                let e = t.eye;
                if let Some(prev) = self.latest[e] {
                    let dt = t.board_us.saturating_sub(prev.board_us) as f64 * 1e-6;
                    if dt > 0.0 {
                        for i in 0..3 {
                            peak[e] = peak[e].max(counts_to_deg((t.counts[i] - prev.counts[i]).abs(), 0) / dt);
                        }
                    }
                }
                if moved_at[e].is_none() && t.counts != start_counts[e] {
                    moved_at[e] = Some(t.board_us);
                }
                if t.counts == target_counts[e] {
                    arrived_at[e].get_or_insert(t.board_us);
                    still[e] += 1;
                } else {
                    arrived_at[e] = None;
                    still[e] = 0;
                }
                self.latest[e] = Some(t);
            }
        }
        let measured_ms = [0, 1].map(|e| match (moved_at[e], arrived_at[e]) {
            (Some(m), Some(a)) => a.saturating_sub(m) as f64 * 1e-3,
            (None, Some(_)) => 0.0,
            _ => f64::NAN,
        });
        Ok(MoveMeasurement { measured_ms, peak_deg_s: peak, arrived: still.iter().all(|&n| n >= ARRIVED) })
    }

    /// What the tracker saw so far.
    pub fn stats(&self) -> EncoderStats {
        self.tracker.stats()
    }

    /// Homed samples the tracker emitted (what the runtime would have consumed).
    pub fn homed_samples(&self) -> u64 {
        self.homed_samples
    }
}
