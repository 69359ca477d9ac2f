//! Minimum-jerk point-to-point motion in link space (saccades): every link follows
//! `theta(t) = from + (to - from) s(t / T)`, `s(u) = 10 u^3 - 15 u^4 + 6 u^5`, so all links start
//! and arrive together with zero velocity and acceleration. The peak speed of a link is
//! `15/8 |to - from| / T` at mid-course; the duration is the shortest that keeps every link at or
//! below the peak speed (the paper's 1561 deg/s, [`PEAK_SPEED_DEG_S`]).

/// The paper's peak speed (deg/s).
pub const PEAK_SPEED_DEG_S: f64 = 1561.0;

/// Peak speed of a minimum-jerk profile over its mean speed.
pub const PEAK_OVER_MEAN: f64 = 15.0 / 8.0;

/// One minimum-jerk move of the three links (deg, s).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MinJerk {
    pub from: [f64; 3],
    pub to: [f64; 3],
    pub duration_s: f64,
}

impl MinJerk {
    /// The shortest move whose fastest link peaks at `peak_deg_s`.
    pub fn with_peak_speed(from: [f64; 3], to: [f64; 3], peak_deg_s: f64) -> MinJerk {
        let travel = (0..3).map(|i| (to[i] - from[i]).abs()).fold(0.0, f64::max);
        MinJerk { from, to, duration_s: PEAK_OVER_MEAN * travel / peak_deg_s }
    }

    /// Normalised progress s(u) and its derivative ds/du for u = t / T clamped to [0, 1].
    fn progress(&self, t_s: f64) -> (f64, f64) {
        if self.duration_s <= 0.0 {
            return (1.0, 0.0);
        }
        let u = (t_s / self.duration_s).clamp(0.0, 1.0);
        let u2 = u * u;
        (u2 * u * (10.0 - 15.0 * u + 6.0 * u2), 30.0 * u2 * (1.0 - u) * (1.0 - u))
    }

    /// Link angles (deg) at time `t_s` since the start (held outside [0, T]).
    pub fn at(&self, t_s: f64) -> [f64; 3] {
        let (s, _) = self.progress(t_s);
        std::array::from_fn(|i| self.from[i] + (self.to[i] - self.from[i]) * s)
    }

    /// Link speeds (deg/s) at time `t_s`.
    pub fn speed(&self, t_s: f64) -> [f64; 3] {
        if self.duration_s <= 0.0 || !(0.0..=self.duration_s).contains(&t_s) {
            return [0.0; 3];
        }
        let (_, ds) = self.progress(t_s);
        std::array::from_fn(|i| (self.to[i] - self.from[i]) * ds / self.duration_s)
    }

    /// The largest link speed of the move (deg/s), at mid-course.
    pub fn peak_speed(&self) -> f64 {
        self.speed(0.5 * self.duration_s).iter().fold(0.0, |m, v| m.max(v.abs()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_30_deg_saccade_at_the_paper_speed() {
        let m = MinJerk::with_peak_speed([0.0, 5.0, -3.0], [30.0, -5.0, 0.0], PEAK_SPEED_DEG_S);
        assert!((m.duration_s - 1.875 * 30.0 / 1561.0).abs() < 1e-15, "{}", m.duration_s);
        assert!((m.peak_speed() - PEAK_SPEED_DEG_S).abs() < 1e-9);
        assert_eq!(m.at(-1.0), m.from);
        assert_eq!(m.at(m.duration_s), m.to);
        assert_eq!(m.at(1.0), m.to);
        let mid = m.at(0.5 * m.duration_s);
        for i in 0..3 {
            assert!((mid[i] - 0.5 * (m.from[i] + m.to[i])).abs() < 1e-12);
        }
        // Speeds never exceed the peak, start and end at rest; the speed integrates to the travel.
        let n = 10_000;
        let dt = m.duration_s / n as f64;
        let mut pos = m.from;
        for k in 0..n {
            let v = m.speed((k as f64 + 0.5) * dt);
            for i in 0..3 {
                assert!(v[i].abs() <= PEAK_SPEED_DEG_S + 1e-9);
                pos[i] += v[i] * dt;
            }
        }
        for i in 0..3 {
            assert!((pos[i] - m.to[i]).abs() < 1e-6, "{pos:?}");
        }
        assert_eq!(m.speed(0.0), [0.0; 3]);
        let still = MinJerk::with_peak_speed([1.0; 3], [1.0; 3], PEAK_SPEED_DEG_S);
        assert_eq!((still.duration_s, still.at(0.0)), (0.0, [1.0; 3]));
    }
}
