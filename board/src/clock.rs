//! Board time -> the host's CLOCK_MONOTONIC.
use std::collections::VecDeque;

/// Maps board time to CLOCK_MONOTONIC. Each frame gives `host_rx - board = offset + drift *
/// board + latency`, latency >= 0 and jittery; the lower envelope of that difference is the
/// clock relation. Drift is fitted over the window's per-block minima, the offset is the
/// window's minimum after removing the drift. The constant part of the transport latency cannot
/// be told from the offset on a one-way link; it is calibrated as the eye's encoder_time_offset.
#[derive(Debug, Clone)]
pub struct ClockMap {
    obs: VecDeque<(f64, f64)>,
    capacity: usize,
    fit: Option<(f64, f64)>,
}

impl ClockMap {
    /// A map fitting over the last `capacity` frames (at least 16).
    pub fn new(capacity: usize) -> Self {
        ClockMap { obs: VecDeque::with_capacity(capacity), capacity: capacity.max(16), fit: None }
    }

    /// Forgets every observation (after a board reset).
    pub fn reset(&mut self) {
        self.obs.clear();
        self.fit = None;
    }

    /// Records a frame's board time (us) and its host receive time (s, CLOCK_MONOTONIC).
    pub fn observe(&mut self, board_us: u64, host_s: f64) {
        if self.obs.len() == self.capacity {
            self.obs.pop_front();
        }
        let b = board_us as f64 * 1e-6;
        self.obs.push_back((b, host_s - b));
        self.refit();
    }

    fn refit(&mut self) {
        let n = self.obs.len();
        if n < 8 {
            self.fit = self.obs.iter().map(|o| o.1).reduce(f64::min).map(|m| (m, 0.0));
            return;
        }
        // Minima of 8 blocks carry the envelope; a line through them gives the drift.
        let block = n / 8;
        let mins: Vec<(f64, f64)> = (0..8)
            .map(|k| {
                self.obs.iter().skip(k * block).take(block).copied().fold((0.0, f64::MAX), |m, o| {
                    if o.1 < m.1 {
                        o
                    } else {
                        m
                    }
                })
            })
            .collect();
        let (mx, my) = mins.iter().fold((0.0, 0.0), |a, m| (a.0 + m.0 / 8.0, a.1 + m.1 / 8.0));
        let sxx: f64 = mins.iter().map(|m| (m.0 - mx).powi(2)).sum();
        let sxy: f64 = mins.iter().map(|m| (m.0 - mx) * (m.1 - my)).sum();
        let drift = if sxx > 0.0 { sxy / sxx } else { 0.0 };
        let offset = self.obs.iter().map(|o| o.1 - drift * o.0).fold(f64::MAX, f64::min);
        self.fit = Some((offset, drift));
    }

    /// CLOCK_MONOTONIC time (s) of a board time (us), once anything was observed.
    pub fn to_host(&self, board_us: u64) -> Option<f64> {
        let (offset, drift) = self.fit?;
        let b = board_us as f64 * 1e-6;
        Some(b + offset + drift * b)
    }
}
