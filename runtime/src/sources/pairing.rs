//! Left/right frames -> [`FramePair`]s.
//!
//! The two OV8856 are hardware-synchronised, so frames taken together start exposing within
//! microseconds; the capture threads deliver them in any interleaving. Pairs are decided by the
//! start-of-exposure timestamps, within a tolerance (2 ms by default, a twentieth of the 40 ms
//! frame period, so a match is never ambiguous). Sequence numbers are not compared across the
//! cameras: each V4L2 device counts from its own STREAMON, so their offset is arbitrary. Within a
//! stream they reveal frames the driver dropped (a jump), which are counted.
//!
//! Every frame offered is accounted for exactly once: delivered in a pair, dropped as unpaired (its
//! partner never came, or came too late to be matched), dropped as out of order (timestamp or
//! sequence not after the previous frame of its stream), or still waiting ([`Pairer::pending`]).
//! Memory is bounded by [`PairerConfig::window`] frames per side; nothing panics on any input.
use std::collections::VecDeque;

use abvs_runtime_core::messages::{Frame, FramePair};

/// Which camera a frame came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    /// The left eye's camera.
    Left,
    /// The right eye's camera.
    Right,
}

impl Side {
    /// 0 for left, 1 for right: the index into the `[left, right]` arrays of [`PairStats`].
    pub fn index(self) -> usize {
        match self {
            Side::Left => 0,
            Side::Right => 1,
        }
    }
}

/// Pairing parameters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PairerConfig {
    /// Largest |t_left - t_right| of a pair, ns (2 ms: hardware-synchronised cameras).
    pub tolerance_ns: i64,
    /// Frames one side may wait for its partner; beyond this the oldest is dropped as unpaired
    /// (a stalled camera must not hold the other one's frames forever).
    pub window: usize,
}

impl Default for PairerConfig {
    fn default() -> Self {
        PairerConfig { tolerance_ns: 2_000_000, window: 4 }
    }
}

/// Counts of what happened to the frames offered (left, right).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct PairStats {
    /// Frames offered to [`Pairer::push`].
    pub input: [u64; 2],
    /// Pairs emitted.
    pub delivered: u64,
    /// Frames dropped because no partner came within the tolerance.
    pub unpaired: [u64; 2],
    /// Frames dropped because their timestamp or sequence was not after the previous one.
    pub out_of_order: [u64; 2],
    /// Frames the driver never delivered, from jumps in the sequence numbers (not part of `input`).
    pub dropped: [u64; 2],
}

impl PairStats {
    /// Frames offered and not delivered (unpaired or out of order); `2 * delivered + discarded() +
    /// pending == input[0] + input[1]`.
    pub fn discarded(&self) -> u64 {
        self.unpaired.iter().chain(&self.out_of_order).sum()
    }
}

/// Pairs left and right frames by start-of-exposure time; see the module doc.
#[derive(Debug)]
pub struct Pairer {
    cfg: PairerConfig,
    queues: [VecDeque<Frame>; 2],
    last: [Option<(u64, i64)>; 2],
    next_pair_seq: u64,
    stats: PairStats,
}

impl Pairer {
    /// A pairer; a window of 0 is raised to 1 and a negative tolerance to 0.
    pub fn new(cfg: PairerConfig) -> Self {
        let cfg = PairerConfig { tolerance_ns: cfg.tolerance_ns.max(0), window: cfg.window.max(1) };
        let q = || VecDeque::with_capacity(cfg.window + 1);
        Pairer { cfg, queues: [q(), q()], last: [None, None], next_pair_seq: 0, stats: PairStats::default() }
    }

    /// The pairing's configuration.
    pub fn config(&self) -> PairerConfig {
        self.cfg
    }

    /// What the pairer counted so far.
    pub fn stats(&self) -> PairStats {
        self.stats
    }

    /// Frames waiting for a partner.
    pub fn pending(&self) -> usize {
        self.queues[0].len() + self.queues[1].len()
    }

    /// Offers one frame; returns the pair it completes, if any.
    pub fn push(&mut self, side: Side, frame: Frame) -> Option<FramePair> {
        let s = side.index();
        let o = 1 - s;
        self.stats.input[s] += 1;
        if let Some((prev_seq, prev_t)) = self.last[s] {
            if frame.t_start_ns <= prev_t || frame.seq <= prev_seq {
                self.stats.out_of_order[s] += 1;
                return None;
            }
            self.stats.dropped[s] = self.stats.dropped[s].saturating_add(frame.seq - prev_seq - 1);
        }
        self.last[s] = Some((frame.seq, frame.t_start_ns));

        let t = i128::from(frame.t_start_ns);
        let tol = i128::from(self.cfg.tolerance_ns);
        // The other side's waiting frames older than t - tol can only be matched by a later frame of
        // this side, which is later still: they are dead.
        while self.queues[o].front().is_some_and(|f| i128::from(f.t_start_ns) < t - tol) {
            self.queues[o].pop_front();
            self.stats.unpaired[o] += 1;
        }
        // Closest partner within the tolerance; the ones before it can no longer pair (pairs increase).
        let best = self.queues[o]
            .iter()
            .take_while(|f| i128::from(f.t_start_ns) <= t + tol)
            .enumerate()
            .min_by_key(|(_, f)| (i128::from(f.t_start_ns) - t).abs())
            .map(|(i, _)| i);
        if let Some(i) = best {
            for _ in 0..i {
                self.queues[o].pop_front();
                self.stats.unpaired[o] += 1;
            }
            let partner = self.queues[o].pop_front()?;
            let (left, right) = if side == Side::Left { (frame, partner) } else { (partner, frame) };
            let pair = FramePair { seq: self.next_pair_seq, left, right };
            self.next_pair_seq += 1;
            self.stats.delivered += 1;
            return Some(pair);
        }
        if !self.queues[o].is_empty() {
            // The other side already holds a later frame than t + tol: no partner can come any more.
            self.stats.unpaired[s] += 1;
            return None;
        }
        if self.queues[s].len() >= self.cfg.window {
            self.queues[s].pop_front();
            self.stats.unpaired[s] += 1;
        }
        self.queues[s].push_back(frame);
        None
    }

    /// Drops every waiting frame as unpaired (end of stream).
    pub fn flush(&mut self) {
        for s in 0..2 {
            self.stats.unpaired[s] += self.queues[s].len() as u64;
            self.queues[s].clear();
        }
    }

    /// Drops waiting frames that started before `t_ns` (e.g. now minus a few frame periods, when
    /// one camera has stopped delivering), so they do not wait for a partner that will not come.
    pub fn expire_before(&mut self, t_ns: i64) {
        for s in 0..2 {
            while self.queues[s].front().is_some_and(|f| f.t_start_ns < t_ns) {
                self.queues[s].pop_front();
                self.stats.unpaired[s] += 1;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn f(seq: u64, t_ms: f64) -> Frame {
        Frame {
            seq,
            t_start_ns: (t_ms * 1e6) as i64,
            exposure_ns: 1_000_000,
            readout_anchor: 0.0,
            width: 0,
            height: 0,
            gray: Vec::new(),
        }
    }

    #[test]
    fn pairs_within_tolerance_in_any_order() {
        let mut p = Pairer::new(PairerConfig::default());
        assert!(p.push(Side::Left, f(10, 0.0)).is_none());
        assert!(p.push(Side::Left, f(11, 40.0)).is_none());
        let a = p.push(Side::Right, f(500, 0.5)).unwrap();
        assert_eq!((a.seq, a.left.seq, a.right.seq), (0, 10, 500));
        let b = p.push(Side::Right, f(501, 39.0)).unwrap();
        assert_eq!((b.seq, b.left.seq, b.right.seq), (1, 11, 501));
        assert_eq!(p.stats().delivered, 2);
    }

    #[test]
    fn gaps_and_late_frames_are_counted() {
        let mut p = Pairer::new(PairerConfig::default());
        p.push(Side::Left, f(0, 0.0));
        p.push(Side::Left, f(2, 80.0)); // seq 1 dropped by the driver
        assert!(p.push(Side::Right, f(0, 0.1)).is_some());
        assert!(p.push(Side::Right, f(1, 40.1)).is_none()); // its left partner was dropped
        assert!(p.push(Side::Right, f(2, 80.1)).is_some());
        p.push(Side::Right, f(2, 120.0)); // repeated sequence
        p.push(Side::Right, f(3, 70.0)); // time going back
        let s = p.stats();
        assert_eq!(s.dropped, [1, 0]);
        assert_eq!(s.unpaired, [0, 1]);
        assert_eq!(s.out_of_order, [0, 2]);
        assert_eq!(2 * s.delivered + s.discarded() + p.pending() as u64, s.input[0] + s.input[1]);
    }

    #[test]
    fn window_bounds_a_stalled_partner() {
        let mut p = Pairer::new(PairerConfig { window: 3, ..Default::default() });
        for i in 0..10 {
            p.push(Side::Left, f(i, i as f64 * 40.0));
        }
        assert_eq!(p.pending(), 3);
        assert_eq!(p.stats().unpaired, [7, 0]);
        p.flush();
        assert_eq!(p.stats().unpaired, [10, 0]);
    }

    #[test]
    fn expire_drops_only_older_frames() {
        let mut p = Pairer::new(PairerConfig::default());
        p.push(Side::Right, f(0, 0.0));
        p.push(Side::Right, f(1, 40.0));
        p.expire_before(20_000_000);
        assert_eq!((p.pending(), p.stats().unpaired), (1, [0, 1]));
        assert!(p.push(Side::Left, f(7, 40.5)).is_some());
    }
}
