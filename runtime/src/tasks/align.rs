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
use crate::tasks::motion::{node_time_ns, SPEED_DT_S, WIDE_DT_S};
use abvs_eye::UnitModel;
use abvs_runtime_core::error::{Result, RuntimeError};
use abvs_runtime_core::messages::Work;
use abvs_runtime_core::params::MotionConfig;
use abvs_runtime_core::source::EncoderFeed;
use abvs_runtime_core::stage::{Stage, StageContext};
use abvs_runtime_core::stats::RunStats;
use std::collections::VecDeque;

use abvs_runtime_core::messages::EncoderSample;

/// Counts of what the track refused, for the runtime's statistics.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TrackStats {
    /// Samples taken into the track.
    pub accepted: u64,
    /// Samples refused: not after the previous one.
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
    /// What the track took and refused.
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

/// The time-alignment stage: both eyes' link angles at their frames' instants ([`Work::theta`]), either
/// side of it for the eyes' speed, and at the row-band nodes of the per-row correction ([`Work::motion`]),
/// from the source's encoder feed.
pub struct AlignStage {
    tracks: [EncoderTrack; 2],
    encoders: Option<Box<dyn EncoderFeed>>,
    motion: MotionConfig,
}

impl AlignStage {
    /// `latency_s`: each eye's encoder latency (its unit model's encoder_time_offset; 0 without one).
    pub fn new(latency_s: [f64; 2]) -> Self {
        let mut tracks = [EncoderTrack::new(2000), EncoderTrack::new(2000)];
        tracks[0].latency_s = latency_s[0];
        tracks[1].latency_s = latency_s[1];
        AlignStage { tracks, encoders: None, motion: MotionConfig::default() }
    }

    /// Per-row correction and the encoder offset override of `motion`.
    pub fn with_motion(mut self, motion: MotionConfig) -> Self {
        if let Some(t) = motion.time_offset_s {
            self.tracks.iter_mut().zip(t).for_each(|(tr, t)| tr.latency_s = t);
        }
        self.motion = motion;
        self
    }

    /// Both eyes' encoder tracks (left, right).
    pub fn tracks(&self) -> &[EncoderTrack; 2] {
        &self.tracks
    }
}

impl Stage for AlignStage {
    fn name(&self) -> &'static str {
        "align"
    }

    fn start(&mut self, ctx: &mut StageContext) -> Result<()> {
        self.encoders = ctx.encoders.take();
        if self.encoders.is_none() {
            return Err(RuntimeError::Invalid("align: the source's encoder feed was taken by another stage".into()));
        }
        Ok(())
    }

    fn process(&mut self, w: &mut Work) -> Result<()> {
        let tracks = &mut self.tracks;
        let m = &mut w.motion;
        if let Some(encoders) = self.encoders.as_mut() {
            // encoders up to a little past the frame's last row (interpolation needs the samples after it)
            let latest = w.t_frame_ns.max(w.t_right_ns) + m.readout_ns / 2 + 20_000_000;
            let until = latest + (tracks[0].latency_s.max(tracks[1].latency_s) * 1e9) as i64;
            // A refused sample is counted by its track.
            encoders.feed(until, &mut |eye, s| {
                if let Some(t) = tracks.get_mut(eye) {
                    let _ = t.push(s);
                }
            });
        }
        let bands = self.motion.bands_for(m.readout_ns);
        for (eye, t_ns) in [w.t_frame_ns, w.t_right_ns].into_iter().enumerate() {
            let track = &tracks[eye];
            let t = t_ns as f64 * 1e-9;
            w.theta[eye] = track.at_camera_time(t)?;
            m.theta_pm[eye] = [track.at_camera_time(t - SPEED_DT_S)?, track.at_camera_time(t + SPEED_DT_S)?];
            m.theta_wide[eye] = [track.at_camera_time(t - WIDE_DT_S)?, track.at_camera_time(t + WIDE_DT_S)?];
            let nodes = &mut m.band_theta[eye];
            nodes.clear();
            if bands > 0 {
                for b in 0..=bands {
                    nodes.push(track.at_camera_time(node_time_ns(t_ns, m.readout_ns, b, bands) as f64 * 1e-9)?);
                }
            }
        }
        Ok(())
    }

    fn failure(&self, e: &RuntimeError) -> &'static str {
        abvs_runtime_core::stage::timing_failure(e).unwrap_or("kinematics or rectification failed")
    }

    fn finish(&mut self, stats: &mut RunStats) {
        let refused = self.tracks[0].stats.non_monotonic + self.tracks[1].stats.non_monotonic;
        stats.extra.insert("encoder_samples_refused".into(), serde_json::json!(refused));
    }
}
