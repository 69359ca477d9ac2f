//! Time alignment: link angles at a camera frame's mid-exposure time, from the encoder stream.
//!
//! Encoder samples arrive stamped on CLOCK_MONOTONIC (after the drive board's clock mapping).
//! The eye's encoder_time_offset (unit model) says an encoder sample stamped `t` was read at
//! camera time `t - latency`; so the angles at camera time `t_cam` are the stream evaluated at
//! encoder time `t_cam + latency`.
//!
//! Interpolation is cubic Hermite with Catmull-Rom slopes (monotone in time, C1): at saccade speed
//! (1561 deg/s, ~2e5 deg/s^2) linear interpolation between 1 kHz samples errs by up to
//! `a h^2 / 8` ~ 0.02 deg, the whole error budget; the cubic's error is two orders smaller.
use crate::error::{Result, RuntimeError};
use abvs_eye::UnitModel;
use std::collections::VecDeque;

/// One encoder reading of the three links (deg, homed) at a CLOCK_MONOTONIC time (s).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EncoderSample {
    pub t_s: f64,
    pub theta_deg: [f64; 3],
}

/// Counts of what the track refused, for the runtime's statistics.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TrackStats {
    pub accepted: u64,
    pub non_monotonic: u64,
}

/// A bounded history of one eye's encoder stream.
#[derive(Debug, Clone)]
pub struct EncoderTrack {
    samples: VecDeque<EncoderSample>,
    capacity: usize,
    /// Longest interval (s) interpolated across; a longer gap (dropped packets) is refused.
    pub max_gap_s: f64,
    /// encoder_time_offset of the eye (s): encoder stamp = camera time + latency.
    pub latency_s: f64,
    pub stats: TrackStats,
}

impl EncoderTrack {
    /// `capacity` samples (1 kHz stream: 500 keeps half a second).
    pub fn new(capacity: usize) -> Self {
        EncoderTrack {
            samples: VecDeque::with_capacity(capacity),
            capacity: capacity.max(4),
            max_gap_s: 0.005,
            latency_s: 0.0,
            stats: TrackStats::default(),
        }
    }

    /// Takes the latency from the unit model's encoder_time_offset (0 when switched off).
    pub fn for_unit(capacity: usize, unit: &UnitModel) -> Self {
        let mut t = EncoderTrack::new(capacity);
        t.latency_s = unit.encoder_time_for_camera(0.0).abs();
        t
    }

    /// Appends a sample; a sample not after the last one is refused and counted.
    pub fn push(&mut self, s: EncoderSample) -> Result<()> {
        if !s.t_s.is_finite() || s.theta_deg.iter().any(|v| !v.is_finite()) {
            return Err(RuntimeError::Invalid(format!("encoder sample with a non-finite value: {s:?}")));
        }
        if let Some(last) = self.samples.back() {
            // Equal stamps are refused too: two readings cannot share an instant.
            if s.t_s.partial_cmp(&last.t_s) != Some(std::cmp::Ordering::Greater) {
                self.stats.non_monotonic += 1;
                return Err(RuntimeError::NonMonotonic { stream: "encoder", t: s.t_s, prev: last.t_s });
            }
        }
        if self.samples.len() == self.capacity {
            self.samples.pop_front();
        }
        self.samples.push_back(s);
        self.stats.accepted += 1;
        Ok(())
    }

    /// Link angles (deg) at camera time `t_cam` (s), e.g. a frame's mid-exposure.
    pub fn at_camera_time(&self, t_cam: f64) -> Result<[f64; 3]> {
        self.at_encoder_time(t_cam + self.latency_s)
    }

    /// Link angles (deg) at encoder time `t` (s), cubic Hermite between the bracketing samples.
    pub fn at_encoder_time(&self, t: f64) -> Result<[f64; 3]> {
        let n = self.samples.len();
        let span = |from: f64, to: f64| RuntimeError::OutOfSpan { stream: "encoder", t, from, to };
        if n < 2 {
            return Err(span(f64::NAN, f64::NAN));
        }
        let (first, last) = (self.samples[0].t_s, self.samples[n - 1].t_s);
        if !(t >= first && t <= last) {
            return Err(span(first, last));
        }
        // First sample at or after t (binary search: the deque is sorted by time); a query on a
        // sample is that sample, otherwise t lies strictly inside (t_k, t_k+1).
        let j = self.samples.partition_point(|s| s.t_s < t);
        if self.samples[j].t_s == t {
            return Ok(self.samples[j].theta_deg);
        }
        let k = j - 1;
        let (p0, p1) = (self.samples[k], self.samples[k + 1]);
        let h = p1.t_s - p0.t_s;
        if h > self.max_gap_s {
            return Err(RuntimeError::Gap { stream: "encoder", t, gap_ms: h * 1e3, max_ms: self.max_gap_s * 1e3 });
        }
        // Catmull-Rom slopes from the neighbours (one-sided at the ends), per unit time.
        let prev = if k > 0 { self.samples[k - 1] } else { p0 };
        let next = if k + 2 < n { self.samples[k + 2] } else { p1 };
        let u = (t - p0.t_s) / h;
        let (h00, h10, h01, h11) = (
            (1.0 + 2.0 * u) * (1.0 - u) * (1.0 - u),
            u * (1.0 - u) * (1.0 - u),
            u * u * (3.0 - 2.0 * u),
            u * u * (u - 1.0),
        );
        Ok(std::array::from_fn(|i| {
            let m0 = (p1.theta_deg[i] - prev.theta_deg[i]) / (p1.t_s - prev.t_s);
            let m1 = (next.theta_deg[i] - p0.theta_deg[i]) / (next.t_s - p0.t_s);
            h00 * p0.theta_deg[i] + h10 * h * m0 + h01 * p1.theta_deg[i] + h11 * h * m1
        }))
    }

    /// The time span currently buffered (s).
    pub fn span(&self) -> Option<(f64, f64)> {
        Some((self.samples.front()?.t_s, self.samples.back()?.t_s))
    }
}
