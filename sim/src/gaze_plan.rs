//! Where a synthetic session's eyes look: a periodic plan of fixations, smooth pursuits and saccades
//! between 3D targets in the scene (world = left home camera frame, metres).
//!
//! - Fixation: the target holds still for 0.15-0.35 s.
//! - Smooth pursuit: the target glides to another point of the scene (nearer or farther too, so the eyes
//!   verge) with a bell-shaped speed, `v(s) ~ 1 - cos(2 pi s)` over the pursuit's duration: it starts and
//!   ends at rest and peaks mid-way, so a session sweeps every speed up to the peak. The duration is chosen
//!   so the gaze's angular speed peaks at the requested value (the pursuit's `peak_deg_s`).
//! - Saccade: a minimum-jerk jump to the next target, peak speed growing with amplitude up to the eyes'
//!   1561 deg/s (main sequence).
//!
//! The plan is periodic (the last saccade returns to the first target), so a looped replay is seamless.
use nalgebra::Vector3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// The eyes' fastest saccade (deg/s).
pub const SACCADE_PEAK_DEG_S: f64 = 1561.0;
/// Depth range (z, m, world = left home camera frame) of the targets by default.
pub const DEFAULT_TARGET_DEPTH_M: [f64; 2] = [0.55, 1.3];
/// Point between the two eyes from which gaze angles are measured (world, m).
const CYCLOPEAN: Vector3<f64> = Vector3::new(-0.0325, 0.0, 0.0);

struct Segment {
    /// End of the fixation's hold (start of the pursuit, or of the saccade without one).
    hold_end: f64,
    /// End of the pursuit (= hold_end without one); the saccade runs from here to `end`.
    pursuit_end: f64,
    end: f64,
    from: Vector3<f64>,
    /// Where the pursuit takes the target (= from without one).
    glide_to: Vector3<f64>,
    to: Vector3<f64>,
}

/// A periodic gaze plan: the fixation target at any time.
pub struct GazePlan {
    segments: Vec<Segment>,
    pub period: f64,
}

fn angle_deg(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    (a - CYCLOPEAN).angle(&(b - CYCLOPEAN)).to_degrees()
}

/// Fraction of a pursuit's path covered at fraction `s` of its duration (speed ~ 1 - cos(2 pi s)).
fn glide(s: f64) -> f64 {
    let s = s.clamp(0.0, 1.0);
    s - (2.0 * std::f64::consts::PI * s).sin() / (2.0 * std::f64::consts::PI)
}

impl GazePlan {
    /// A plan of `period` seconds. `pursuit_peak_deg_s`: the fastest pursuit (each pursuit peaks at 0.6-1.0
    /// of it); 0 = fixations and saccades only. The targets' depth z (m) is drawn uniformly from `depth_m`
    /// ([`DEFAULT_TARGET_DEPTH_M`] unless a session asks otherwise: the same draws, other values).
    pub fn new(rng: &mut ChaCha8Rng, period: f64, pursuit_peak_deg_s: f64, depth_m: [f64; 2]) -> GazePlan {
        let target = |rng: &mut ChaCha8Rng| {
            Vector3::new(rng.gen_range(-0.3..0.3), rng.gen_range(-0.22..0.2), rng.gen_range(depth_m[0]..depth_m[1]))
        };
        let saccade_s = |from: &Vector3<f64>, to: &Vector3<f64>| {
            let amp = angle_deg(from, to).max(1.0);
            let vpeak = (200.0 + 40.0 * amp).min(SACCADE_PEAK_DEG_S);
            (1.875 * amp / vpeak).max(0.025)
        };
        let first = target(rng);
        let mut segments = Vec::new();
        let (mut t, mut cur) = (0.0, first);
        loop {
            let hold = rng.gen_range(0.15..0.35f64).min(period * 0.6);
            let mut glide_to = cur;
            let mut pursuit_s = 0.0;
            if pursuit_peak_deg_s > 0.0 && rng.gen_bool(0.6) {
                // a target at least 8 deg away; the duration makes the angular speed peak at `peak`
                let peak = pursuit_peak_deg_s * rng.gen_range(0.6..1.0);
                let mut p = target(rng);
                for _ in 0..8 {
                    if angle_deg(&cur, &p) >= 8.0 {
                        break;
                    }
                    p = target(rng);
                }
                // peak of d/dt glide = 2 / duration: duration = 2 * angle / peak, at most 1.2 s (shorter path)
                let amp = angle_deg(&cur, &p).max(1e-3);
                let dur = 2.0 * amp / peak;
                let (p, dur) = if dur > 1.2 { (cur + (p - cur) * (1.2 / dur), 1.2) } else { (p, dur) };
                glide_to = p;
                pursuit_s = dur;
            }
            let mut next = target(rng);
            let close = t + hold + pursuit_s + saccade_s(&glide_to, &first) + 0.12 > period - 0.2;
            if close && pursuit_s > 0.0 && t + hold + saccade_s(&cur, &first) + 0.12 <= period - 0.2 {
                // no room for this pursuit before the loop closes: hold instead
                glide_to = cur;
                pursuit_s = 0.0;
            }
            let last = t + hold + pursuit_s + saccade_s(&glide_to, &first) + 0.12 > period - 0.2;
            if last && pursuit_s > 0.0 {
                // the loop closes after this fixation: no pursuit may run past the period's end
                glide_to = cur;
                pursuit_s = 0.0;
            }
            if last {
                next = first;
            }
            let sacc = saccade_s(&glide_to, &next);
            let hold_end = t + hold;
            let pursuit_end = hold_end + pursuit_s;
            let end = if last { period } else { (pursuit_end + sacc).min(period) };
            segments.push(Segment { hold_end, pursuit_end, end, from: cur, glide_to, to: next });
            cur = next;
            t = end;
            if last {
                break;
            }
        }
        GazePlan { segments, period }
    }

    /// The fixation target at time `t` (s), periodic.
    pub fn at(&self, t: f64) -> Vector3<f64> {
        let t = t.rem_euclid(self.period);
        let seg = self.segments.iter().find(|s| t < s.end).unwrap_or_else(|| self.segments.last().expect("segments"));
        if t < seg.hold_end {
            return seg.from;
        }
        if t < seg.pursuit_end {
            let s = (t - seg.hold_end) / (seg.pursuit_end - seg.hold_end);
            return seg.from + (seg.glide_to - seg.from) * glide(s);
        }
        // the saccade: from where the pursuit ended, minimum jerk, so that it lands at `end`
        let sacc = seg.end - seg.pursuit_end;
        let s = ((t - seg.pursuit_end) / sacc.max(1e-9)).clamp(0.0, 1.0);
        let mj = s * s * s * (10.0 - 15.0 * s + 6.0 * s * s);
        seg.glide_to + (seg.to - seg.glide_to) * mj
    }

    /// Time spent in pursuit (s) over one period.
    pub fn pursuit_s(&self) -> f64 {
        self.segments.iter().map(|s| s.pursuit_end - s.hold_end).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    /// Peak angular speed of the target as seen from between the eyes over `[a, b]` (deg/s).
    fn peak_speed(plan: &GazePlan, a: f64, b: f64) -> f64 {
        let dt = 1e-4;
        let mut t = a;
        let mut best: f64 = 0.0;
        while t + dt < b {
            best = best.max(angle_deg(&plan.at(t), &plan.at(t + dt)) / dt);
            t += dt;
        }
        best
    }

    #[test]
    fn pursuits_peak_at_the_requested_speed_and_the_plan_is_periodic() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let plan = GazePlan::new(&mut rng, 4.0, 90.0, DEFAULT_TARGET_DEPTH_M);
        assert!(plan.pursuit_s() > 0.3, "pursuit {} s", plan.pursuit_s());
        for s in &plan.segments {
            if s.pursuit_end > s.hold_end {
                let v = peak_speed(&plan, s.hold_end, s.pursuit_end);
                // peak in [0.6, 1.0] x 90 deg/s, or less when the path was shortened to 1.2 s
                assert!((10.0..=92.0).contains(&v), "pursuit peak {v} deg/s");
            }
        }
        assert!((plan.at(0.0) - plan.at(4.0)).norm() < 1e-12);
        assert!((plan.at(-0.5) - plan.at(3.5)).norm() < 1e-12);
        let still = GazePlan::new(&mut ChaCha8Rng::seed_from_u64(3), 4.0, 0.0, DEFAULT_TARGET_DEPTH_M);
        assert_eq!(still.pursuit_s(), 0.0);
    }

    #[test]
    fn the_targets_stay_in_the_requested_depth_range() {
        // pursuits and saccades blend two targets, so every point of the plan lies between them in depth
        let plan = GazePlan::new(&mut ChaCha8Rng::seed_from_u64(5), 4.0, 90.0, [1.5, 2.0]);
        let z: Vec<f64> = (0..4000).map(|i| plan.at(i as f64 * 1e-3).z).collect();
        assert!(
            z.iter().all(|z| (1.5..=2.0).contains(z)),
            "{:?}",
            z.iter().fold((9.0f64, 0.0f64), |(a, b), z| (a.min(*z), b.max(*z)))
        );
    }
}
