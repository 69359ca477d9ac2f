//! The live encoder source: serial bytes -> decoded board frames -> per-eye homing -> homed
//! counts stamped on CLOCK_MONOTONIC, as [`EncoderRecord`]s (the rows of a session's
//! encoders.csv and what time alignment consumes).
//!
//! [`EncoderTracker`] is the whole logic, fed bytes and their receive time, so it is tested
//! without a port; [`EncoderStream`] runs it on a thread over any reader (a serial port, or
//! a pseudo-terminal in tests).
//!
//! Start-up: every eye's links roll together through their index markers and
//! [`abvs_eye::encoder::Homing`] finds the home counts (conventions.md, Encoders). Samples are
//! emitted only once their eye is homed; the ones before are counted. A board reset restarts
//! homing of both eyes and the clock mapping (the counts' origin and the board clock are new).
use std::io::{ErrorKind, Read};
use std::sync::atomic::{AtomicBool, AtomicI64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use abvs_eye::encoder::{HomeCounts, Homing, HomingSample, HomingStatus};
use crossbeam_channel::{Receiver, Sender, TrySendError};
use serde::Serialize;

use super::encoder_link::{BoardFrame, ClockMap, Decoder, LinkEvent, LinkStats};
use abvs_runtime_core::session::EncoderRecord;

/// Frames the clock mapping fits over (about 2 s of both eyes at 1 kHz).
pub const CLOCK_WINDOW: usize = 4000;

/// What the tracker saw; per-eye arrays are [left, right].
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct EncoderStats {
    /// The link's frame counts (CRC errors, lost frames, resets).
    pub link: LinkStats,
    /// Home counts of each eye once homed.
    pub home_counts: [Option<[i64; 3]>; 2],
    /// Samples consumed by homing (not emitted).
    pub homing_samples: [u64; 2],
    /// Homing attempts refused (each restarts homing; the last reason is kept).
    pub homing_failures: [u64; 2],
    /// Why the last homing attempt of each eye was refused.
    pub last_homing_error: [Option<String>; 2],
    /// Samples emitted.
    pub samples: [u64; 2],
    /// Homed samples whose mapped time was not after the previous one of their eye (dropped).
    pub out_of_order: [u64; 2],
    /// Frames naming an eye other than 0 or 1 (dropped).
    pub bad_eye: u64,
    /// Records the consumer was too slow to take (dropped, counted here by [`EncoderStream`]).
    pub overflow: u64,
}

#[derive(Debug, Default)]
struct EyeTrack {
    homing: Homing,
    home: Option<HomeCounts>,
    last_t_ns: Option<i64>,
}

/// Bytes -> homed, time-stamped encoder records.
#[derive(Debug)]
pub struct EncoderTracker {
    decoder: Decoder,
    clock: ClockMap,
    eyes: [EyeTrack; 2],
    stats: EncoderStats,
}

impl Default for EncoderTracker {
    fn default() -> Self {
        Self::new()
    }
}

impl EncoderTracker {
    /// A tracker before its first byte: no clock mapping, no eye homed.
    pub fn new() -> Self {
        EncoderTracker {
            decoder: Decoder::new(),
            clock: ClockMap::new(CLOCK_WINDOW),
            eyes: Default::default(),
            stats: EncoderStats::default(),
        }
    }

    /// What it saw so far.
    pub fn stats(&self) -> EncoderStats {
        EncoderStats { link: self.decoder.stats, ..self.stats.clone() }
    }

    /// Whether each eye is homed.
    pub fn homed(&self) -> [bool; 2] {
        [self.eyes[0].home.is_some(), self.eyes[1].home.is_some()]
    }

    /// Feeds bytes received at `host_rx_ns` (CLOCK_MONOTONIC) and appends the records they complete.
    pub fn feed(&mut self, bytes: &[u8], host_rx_ns: i64, out: &mut Vec<EncoderRecord>) {
        for event in self.decoder.feed(bytes) {
            let frame = match event {
                LinkEvent::Frame(f) => f,
                LinkEvent::Reset(f) => {
                    // New counts origin and new board clock: home again, map the clock again.
                    self.clock.reset();
                    for (e, s) in self.eyes.iter_mut().zip(self.stats.home_counts.iter_mut()) {
                        *e = EyeTrack::default();
                        *s = None;
                    }
                    f
                }
            };
            self.clock.observe(frame.board_time_us, host_rx_ns as f64 * 1e-9);
            if let Some(r) = self.track(&frame) {
                out.push(r);
            }
        }
    }

    fn track(&mut self, f: &BoardFrame) -> Option<EncoderRecord> {
        let eye = usize::from(f.eye);
        if eye > 1 {
            self.stats.bad_eye += 1;
            return None;
        }
        let counts = f.counts.map(i64::from);
        let track = &mut self.eyes[eye];
        let Some(home) = track.home else {
            self.stats.homing_samples[eye] += 1;
            let sample = HomingSample { counts, index: [0, 1, 2].map(|i| f.index & (1 << i) != 0) };
            match track.homing.push(sample) {
                Ok(HomingStatus::Done(h)) => {
                    track.home = Some(h);
                    self.stats.home_counts[eye] = Some(h.0);
                }
                Ok(HomingStatus::Pending) => {}
                Err(e) => {
                    self.stats.homing_failures[eye] += 1;
                    self.stats.last_homing_error[eye] = Some(e.to_string());
                    track.homing = Homing::new();
                }
            }
            return None;
        };
        // Mapped with the clock fit as of now: causal, as the runtime would use it live.
        let t_ns = (self.clock.to_host(f.board_time_us)? * 1e9).round() as i64;
        if track.last_t_ns.is_some_and(|last| t_ns <= last) {
            self.stats.out_of_order[eye] += 1;
            return None;
        }
        track.last_t_ns = Some(t_ns);
        self.stats.samples[eye] += 1;
        Some(EncoderRecord {
            t_ns,
            eye: f.eye,
            count1: counts[0] - home.0[0],
            count2: counts[1] - home.0[1],
            count3: counts[2] - home.0[2],
        })
    }
}

/// [`EncoderTracker`] on its own thread, reading a port until stopped or the port fails.
pub struct EncoderStream {
    rx: Receiver<EncoderRecord>,
    shared: Arc<Mutex<(EncoderStats, [bool; 2])>>,
    last_ns: Arc<AtomicI64>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<Result<(), String>>>,
    /// The same port for writing (the drive board's commands), when it was given one.
    commands: Option<(Box<dyn std::io::Write + Send>, String)>,
}

/// Homing and liveness of an [`EncoderStream`], for another thread (the gaze controller's).
#[derive(Clone)]
pub struct EncoderWatch {
    shared: Arc<Mutex<(EncoderStats, [bool; 2])>>,
    last_ns: Arc<AtomicI64>,
}

impl EncoderWatch {
    /// Both eyes' home counts once both are homed.
    pub fn home_counts(&self) -> Option<[[i64; 3]; 2]> {
        let s = self.shared.lock().expect("encoder stats lock");
        match (s.1, s.0.home_counts) {
            ([true, true], [Some(l), Some(r)]) => Some([l, r]),
            _ => None,
        }
    }

    /// CLOCK_MONOTONIC ns at which the newest homed record arrived.
    pub fn last_record_ns(&self) -> Option<i64> {
        Some(self.last_ns.load(Ordering::Relaxed)).filter(|&t| t != i64::MIN)
    }
}

impl EncoderStream {
    /// Starts reading. `name` (the port path) goes into errors. The reader should time out now
    /// and then (a serial port's timeout) so that the thread notices [`EncoderStream::finish`].
    pub fn spawn<R: Read + Send + 'static>(mut reader: R, name: String, capacity: usize) -> Self {
        let (tx, rx): (Sender<EncoderRecord>, _) = crossbeam_channel::bounded(capacity.max(1));
        let shared = Arc::new(Mutex::new((EncoderStats::default(), [false; 2])));
        let stop = Arc::new(AtomicBool::new(false));
        let last_ns = Arc::new(AtomicI64::new(i64::MIN));
        let (sh, st, last) = (shared.clone(), stop.clone(), last_ns.clone());
        let thread = std::thread::Builder::new()
            .name("encoders".into())
            .spawn(move || {
                let mut tracker = EncoderTracker::new();
                let mut buf = vec![0u8; 4096];
                let mut out = Vec::with_capacity(256);
                let mut overflow = 0u64;
                let result = loop {
                    if st.load(Ordering::Relaxed) {
                        break Ok(());
                    }
                    let n = match reader.read(&mut buf) {
                        Ok(0) => break Err(format!("encoder port {name}: end of stream")),
                        Ok(n) => n,
                        Err(e)
                            if matches!(
                                e.kind(),
                                ErrorKind::TimedOut | ErrorKind::WouldBlock | ErrorKind::Interrupted
                            ) =>
                        {
                            continue
                        }
                        Err(e) => break Err(format!("encoder port {name}: {e}")),
                    };
                    let rx_ns = abvs_runtime_core::messages::monotonic_ns();
                    tracker.feed(&buf[..n], rx_ns, &mut out);
                    if !out.is_empty() {
                        last.store(rx_ns, Ordering::Relaxed);
                    }
                    for r in out.drain(..) {
                        if let Err(TrySendError::Full(_)) = tx.try_send(r) {
                            overflow += 1;
                        }
                    }
                    let mut s = sh.lock().expect("encoder stats lock");
                    *s = (EncoderStats { overflow, ..tracker.stats() }, tracker.homed());
                };
                let mut s = sh.lock().expect("encoder stats lock");
                *s = (EncoderStats { overflow, ..tracker.stats() }, tracker.homed());
                result
            })
            .expect("spawning the encoder thread");
        EncoderStream { rx, shared, last_ns, stop, thread: Some(thread), commands: None }
    }

    /// The same port for writing: the drive board's commands ([`crate::sources::board::SerialBoard`]).
    pub fn with_commands(mut self, writer: Box<dyn std::io::Write + Send>, name: String) -> Self {
        self.commands = Some((writer, name));
        self
    }

    /// Homing and liveness, for another thread.
    pub fn watch(&self) -> EncoderWatch {
        EncoderWatch { shared: self.shared.clone(), last_ns: self.last_ns.clone() }
    }

    /// The command side of the port, once (`None` without one).
    pub fn take_board(&mut self) -> Option<crate::sources::board::SerialBoard> {
        let (w, name) = self.commands.take()?;
        Some(crate::sources::board::SerialBoard::new(w, self.watch(), name))
    }

    /// Homed records, in arrival order.
    pub fn records(&self) -> &Receiver<EncoderRecord> {
        &self.rx
    }

    /// What the tracker saw so far.
    pub fn stats(&self) -> EncoderStats {
        self.shared.lock().expect("encoder stats lock").0.clone()
    }

    /// Whether each eye is homed (it may un-home after a board reset).
    pub fn homed(&self) -> [bool; 2] {
        self.shared.lock().expect("encoder stats lock").1
    }

    /// True once the reading thread ended (port error or end of stream).
    pub fn is_finished(&self) -> bool {
        self.thread.as_ref().is_none_or(|t| t.is_finished())
    }

    /// Stops reading; returns the final counts and the port error that ended the stream, if any.
    pub fn finish(mut self) -> (EncoderStats, Option<String>) {
        self.stop.store(true, Ordering::Relaxed);
        let err = match self.thread.take().map(|t| t.join()) {
            Some(Ok(Ok(()))) | None => None,
            Some(Ok(Err(e))) => Some(e),
            Some(Err(_)) => Some("encoder thread panicked".into()),
        };
        (self.stats(), err)
    }
}

impl Drop for EncoderStream {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}
