//! What a subscriber measures of the samples it receives (`abvs echo`): rate, end-to-end latency (receive
//! time - the frame's time, CLOCK_MONOTONIC), valid pixels or points per sample, motion-gated frames; over
//! the whole run and over windows of about a second.
use std::time::Instant;

use super::{FrameHeader, FLAG_MOTION_GATED};

/// Percentile (0..=1) of sorted values, nearest rank; NaN for none.
pub fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len()) - 1;
    sorted[i]
}

/// Rate, latency and size of the samples received over a span.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReceiveSummary {
    /// Samples received.
    pub received: u64,
    /// Samples per second (whole run: between the first and the last sample; 0 for fewer than two).
    pub hz: f64,
    /// Latency median (ms).
    pub p50_ms: f64,
    /// Latency 99th percentile (ms).
    pub p99_ms: f64,
    /// Mean valid pixels (depth, confidence) or points (cloud) per sample.
    pub valid_mean: f64,
    /// Frames published invalid on purpose (the eyes moved too fast), as against lost ones (seq gaps).
    pub motion_gated: u64,
}

/// Accumulates what [`ReceiveSummary`] reports, for the whole run and for the current window.
#[derive(Debug, Clone)]
pub struct ReceiveStats {
    all: Span,
    window: Span,
    first_rx: Option<Instant>,
    last_rx: Option<Instant>,
}

#[derive(Debug, Clone)]
struct Span {
    t0: Instant,
    lat_ms: Vec<f64>,
    valid: u64,
    motion_gated: u64,
}

impl Span {
    fn new(t0: Instant) -> Span {
        Span { t0, lat_ms: Vec::new(), valid: 0, motion_gated: 0 }
    }

    fn summary(&self, hz: f64) -> ReceiveSummary {
        let mut lat = self.lat_ms.clone();
        lat.sort_by(f64::total_cmp);
        let n = lat.len() as u64;
        ReceiveSummary {
            received: n,
            hz,
            p50_ms: percentile(&lat, 0.5),
            p99_ms: percentile(&lat, 0.99),
            valid_mean: if n > 0 { self.valid as f64 / n as f64 } else { 0.0 },
            motion_gated: self.motion_gated,
        }
    }
}

impl Default for ReceiveStats {
    fn default() -> Self {
        let now = Instant::now();
        ReceiveStats { all: Span::new(now), window: Span::new(now), first_rx: None, last_rx: None }
    }
}

impl ReceiveStats {
    /// A sample with header `h` received at `now_ns` (CLOCK_MONOTONIC) / `now`.
    pub fn record(&mut self, h: &FrameHeader, now_ns: i64, now: Instant) {
        let lat_ms = (now_ns - h.t_frame_ns) as f64 * 1e-6;
        let gated = (h.flags & FLAG_MOTION_GATED != 0) as u64;
        for s in [&mut self.all, &mut self.window] {
            s.lat_ms.push(lat_ms);
            s.valid += h.valid as u64;
            s.motion_gated += gated;
        }
        self.first_rx.get_or_insert(now);
        self.last_rx = Some(now);
    }

    /// Samples received so far.
    pub fn received(&self) -> u64 {
        self.all.lat_ms.len() as u64
    }

    /// The window's summary once it spans at least a second at `now`, a new window then started.
    pub fn window_done(&mut self, now: Instant) -> Option<ReceiveSummary> {
        let dt = now.duration_since(self.window.t0).as_secs_f64();
        if dt < 1.0 {
            return None;
        }
        let s = self.window.summary(self.window.lat_ms.len() as f64 / dt);
        self.window = Span::new(now);
        Some(s)
    }

    /// The whole run's summary.
    pub fn summary(&self) -> ReceiveSummary {
        let n = self.received();
        let hz = match (self.first_rx, self.last_rx) {
            (Some(f), Some(l)) if n > 1 && l > f => (n - 1) as f64 / l.duration_since(f).as_secs_f64(),
            _ => 0.0,
        };
        self.all.summary(hz)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn latency_rate_and_gated_frames_over_the_run_and_a_window() {
        assert!(percentile(&[], 0.5).is_nan());
        assert_eq!(percentile(&[1.0, 2.0, 3.0, 4.0], 0.5), 2.0);
        assert_eq!(percentile(&[1.0, 2.0, 3.0, 4.0], 0.99), 4.0);
        let mut s = ReceiveStats::default();
        let t0 = Instant::now();
        let h =
            |t_frame_ns: i64, valid: u32, flags: u32| FrameHeader { t_frame_ns, valid, flags, ..Default::default() };
        s.record(&h(0, 10, 0), 2_000_000, t0);
        s.record(&h(0, 30, FLAG_MOTION_GATED), 4_000_000, t0 + Duration::from_millis(500));
        assert_eq!(s.window_done(t0), None);
        let w = s.window_done(s.window.t0 + Duration::from_secs(2)).expect("a window of 2 s");
        assert_eq!((w.received, w.hz, w.p50_ms, w.p99_ms), (2, 1.0, 2.0, 4.0));
        assert_eq!((w.valid_mean, w.motion_gated), (20.0, 1));
        let all = s.summary();
        assert_eq!((all.received, all.hz, all.motion_gated), (2, 2.0, 1));
        assert_eq!(s.window.lat_ms.len(), 0, "a new window after each report");
    }
}
