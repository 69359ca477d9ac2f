//! Bytes -> homed, time-stamped encoder samples: decoding, per-eye homing and the clock mapping.
//!
//! [`EncoderTracker`] is the whole logic, fed bytes and their receive time, so it is tested without a port
//! ([`crate::stream::EncoderStream`] runs it on a thread over a port).
//!
//! Start-up: every eye's links roll together through their index markers and
//! [`abvs_eye::encoder::Homing`] finds the home counts (conventions.md, Encoders). Samples are
//! emitted only once their eye is homed; the ones before are counted. A board reset restarts
//! homing of both eyes and the clock mapping (the counts' origin and the board clock are new).
use abvs_eye::encoder::{HomeCounts, Homing, HomingSample, HomingStatus};
use serde::Serialize;

use crate::clock::ClockMap;
use crate::decoder::{Decoder, LinkEvent, LinkStats};
use crate::protocol::BoardFrame;

/// One eye's homed counts, stamped on CLOCK_MONOTONIC (a row of a session's encoders.csv).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HomedSample {
    /// When the counts were latched (CLOCK_MONOTONIC ns, from the clock mapping).
    pub t_ns: i64,
    /// Which eye: 0 left, 1 right.
    pub eye: u8,
    /// Homed counts of links 1..3.
    pub counts: [i64; 3],
}

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
    /// Records the consumer was too slow to take (dropped, counted by [`crate::stream::EncoderStream`]).
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

    /// Feeds bytes received at `host_rx_ns` (CLOCK_MONOTONIC) and appends the samples they complete.
    pub fn feed(&mut self, bytes: &[u8], host_rx_ns: i64, out: &mut Vec<HomedSample>) {
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

    fn track(&mut self, f: &BoardFrame) -> Option<HomedSample> {
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
        Some(HomedSample { t_ns, eye: f.eye, counts: [0, 1, 2].map(|i| counts[i] - home.0[i]) })
    }
}
