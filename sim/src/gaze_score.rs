//! The gaze scored against the truth (the simulated head only): a sink that reads each published frame's gaze
//! state and the head's truth of that frame ([`crate::head::TruthFeed`]) and adds to the statistics' `gaze`
//! section:
//!
//! - `fixation_error_deg` {p50, max, n}: over the frames in phase `settled`, each eye's angle between its TRUE
//!   optical axis (the true unit at the true link angles, at the frame's instant) and the ray from its true
//!   optical centre to the goal's point;
//! - `settle_ms` {p50, max, n}: from the frame at which a look_at goal was taken to the first frame where both
//!   eyes are within [`SETTLE_DEG`] of it (frame instants); `goals_unsettled`: goals never within it;
//!   `goals_settled_late`: goals that took longer than their planned saccade + 2 frames;
//! - `pursuit_error_deg` {p50, max, n}: the same angle on the frames in phase `pursuit` that were not gated (the
//!   saccade that catches the point up is), against the pursued point
//!   at the frame's instant (the commanded point moved by the point's velocity, estimated from consecutive
//!   frames, over the frame's lag behind the controller);
//! - `frames_moving_ungated`: frames whose exposure saw the links move more than [`MOVING_DEG`] outside a
//!   pursuit (a frame whose exposure the pursuit's last move covered included) and that were not gated: every
//!   frame that overlaps a saccade must be;
//! - `refused_motion_deg`: the largest true link motion from one frame to the next while the latest goal is
//!   refused (the eyes must not move); `idle_theta_max_deg`: the largest true link angle from home before any
//!   goal (the eyes hold home); `seq_gaps`: frames missing from the published sequence.
//!
//! Memory is bounded: running histograms (`hdrhistogram`), no per-frame lists.
use std::sync::Arc;

use hdrhistogram::Histogram;
use nalgebra::Vector3;

use abvs_runtime_core::gaze::Phase;
use abvs_runtime_core::messages::Published;
use abvs_runtime_core::sink::Sink;
use abvs_runtime_core::stats::RunStats;

use crate::head::{FrameTruth, TruthFeed};

/// Within this of the goal (deg, both eyes), a goal counts as settled for `settle_ms`.
pub const SETTLE_DEG: f64 = 0.1;
/// True link travel over a frame's exposure above which the frame saw the eyes move (deg).
pub const MOVING_DEG: f64 = 0.01;

/// Histogram of angles in micro-degrees (1e-6 .. 180 deg, 3 significant digits).
fn angle_hist() -> Histogram<u64> {
    Histogram::new_with_bounds(1, 180_000_000, 3).expect("valid histogram bounds")
}

/// The goal being scored.
#[derive(Debug, Clone, Copy)]
struct Current {
    id: u64,
    /// The instant of the frame it was taken at (ns).
    taken_ns: i64,
    /// Settled within [`SETTLE_DEG`] yet (or not a look_at goal).
    settled: bool,
    look_at: bool,
    /// The previous frame's commanded point and the controller's instant then (pursuit velocity).
    prev: Option<([f64; 3], i64)>,
}

/// See the module doc.
pub struct GazeScore {
    feed: Arc<TruthFeed>,
    control_delay_ns: i64,
    fixation: Histogram<u64>,
    settle_us: Histogram<u64>,
    pursuit: Histogram<u64>,
    current: Option<Current>,
    goals_unsettled: u64,
    goals_settled_late: u64,
    prev_t_frame_ns: Option<i64>,
    prev_phase: Phase,
    frames_moving_ungated: u64,
    refused_motion_deg: f64,
    idle_theta_max_deg: f64,
    prev_theta: Option<[[f64; 3]; 2]>,
    prev_seq: Option<u64>,
    seq_gaps: u64,
    no_truth: u64,
}

impl GazeScore {
    /// Scores against `feed`; the controller acts on a frame `control_delay_ns` after its last row's exposure
    /// ([`crate::head::SimSource::control_delay_ns`]).
    pub fn new(feed: Arc<TruthFeed>, control_delay_ns: i64) -> GazeScore {
        GazeScore {
            feed,
            control_delay_ns,
            fixation: angle_hist(),
            settle_us: Histogram::new_with_bounds(1, 600_000_000, 3).expect("valid histogram bounds"),
            pursuit: angle_hist(),
            current: None,
            goals_unsettled: 0,
            goals_settled_late: 0,
            prev_t_frame_ns: None,
            prev_phase: Phase::Idle,
            frames_moving_ungated: 0,
            refused_motion_deg: 0.0,
            idle_theta_max_deg: 0.0,
            prev_theta: None,
            prev_seq: None,
            seq_gaps: 0,
            no_truth: 0,
        }
    }

    /// Each eye's angle (deg) between its true optical axis and the ray to `p` (m, left home camera frame).
    pub fn errors_deg(t: &FrameTruth, p: &[f64; 3]) -> [f64; 2] {
        let p = Vector3::from(*p);
        t.world_from_cam.map(|c| (c.r * Vector3::z()).angle(&(p - c.t)).to_degrees())
    }

    fn finish_goal(&mut self) {
        if let Some(c) = self.current.take() {
            if c.look_at && !c.settled {
                self.goals_unsettled += 1;
            }
        }
    }
}

fn summary(h: &Histogram<u64>, scale: f64) -> serde_json::Value {
    if h.is_empty() {
        return serde_json::json!({"p50": null, "max": null, "n": 0});
    }
    let q = |x: u64| x as f64 * scale;
    serde_json::json!({"p50": q(h.value_at_quantile(0.5)), "max": q(h.max()), "n": h.len()})
}

impl Sink for GazeScore {
    fn name(&self) -> &'static str {
        "gaze_score"
    }

    fn consume(&mut self, out: &Published) -> abvs_runtime_core::error::Result<()> {
        if let Some(p) = self.prev_seq {
            self.seq_gaps += out.seq.saturating_sub(p + 1);
        }
        self.prev_seq = Some(out.seq);
        let Some(t) = self.feed.get(out.seq) else {
            self.no_truth += 1;
            return Ok(());
        };
        let g = out.motion.gaze;
        let m = out.motion;
        let frame_ms = self.prev_t_frame_ns.map_or(0.0, |p| (t.t_frame_ns - p) as f64 * 1e-6);
        let last = m.t_start_ns[0].max(m.t_start_ns[1]) + m.readout_ns + m.exposure_ns;
        let now = last + self.control_delay_ns;
        if self.current.is_none_or(|c| c.id != g.goal_id) && g.goal_id != 0 {
            self.finish_goal();
            let look_at = matches!(g.phase, Phase::Saccade | Phase::Settled) && g.commanded_m[0].is_finite();
            self.current =
                Some(Current { id: g.goal_id, taken_ns: t.t_frame_ns, settled: !look_at, look_at, prev: None });
        }
        // (a pursuit's last move, sent at the previous frame, runs over this frame's exposure too)
        let pursuing = g.phase == Phase::Pursuit || self.prev_phase == Phase::Pursuit;
        self.prev_phase = g.phase;
        if t.travel_deg > MOVING_DEG && !m.gated && !pursuing {
            self.frames_moving_ungated += 1;
        }
        if g.phase == Phase::Refused {
            if let Some(p) = self.prev_theta {
                let d = (0..2)
                    .flat_map(|e| (0..3).map(move |i| (e, i)))
                    .map(|(e, i)| (t.theta_deg[e][i] - p[e][i]).abs())
                    .fold(0.0, f64::max);
                self.refused_motion_deg = self.refused_motion_deg.max(d);
            }
        }
        if g.phase == Phase::Idle {
            let far = t.theta_deg.iter().flatten().fold(0.0, |m: f64, x| m.max(x.abs()));
            self.idle_theta_max_deg = self.idle_theta_max_deg.max(far);
        }
        self.prev_theta = Some(t.theta_deg);
        self.prev_t_frame_ns = Some(t.t_frame_ns);
        let record = |h: &mut Histogram<u64>, e: [f64; 2]| {
            for x in e {
                h.saturating_record((x * 1e6).round().max(1.0) as u64);
            }
        };
        if let Some(c) = self.current.as_mut() {
            match g.phase {
                Phase::Saccade | Phase::Settled if c.look_at => {
                    let e = Self::errors_deg(&t, &g.commanded_m);
                    if !c.settled && e[0].max(e[1]) <= SETTLE_DEG {
                        c.settled = true;
                        let took_ms = (t.t_frame_ns - c.taken_ns) as f64 * 1e-6;
                        self.settle_us.saturating_record((took_ms * 1e3).max(1.0) as u64);
                        if took_ms > g.planned_ms + 2.0 * frame_ms {
                            self.goals_settled_late += 1;
                        }
                    }
                    if g.phase == Phase::Settled {
                        record(&mut self.fixation, e);
                    }
                }
                Phase::Pursuit if g.commanded_m[0].is_finite() => {
                    // (the saccade that catches the point up is gated: not the pursuit's error)
                    if let (Some((p0, n0)), false) = (c.prev, m.gated) {
                        let dt = (now - n0) as f64 * 1e-9;
                        if dt > 0.0 {
                            // the pursued point at the frame's instant: the commanded one is the controller's now
                            let back = (now - t.t_frame_ns) as f64 * 1e-9;
                            let p: [f64; 3] =
                                std::array::from_fn(|i| g.commanded_m[i] - (g.commanded_m[i] - p0[i]) / dt * back);
                            record(&mut self.pursuit, Self::errors_deg(&t, &p));
                        }
                    }
                    c.prev = Some((g.commanded_m, now));
                }
                _ => {}
            }
        }
        Ok(())
    }

    fn finish(&mut self, stats: &mut RunStats) {
        self.finish_goal();
        let mut j = stats.extra.remove("gaze").unwrap_or_else(|| serde_json::json!({}));
        j["fixation_error_deg"] = summary(&self.fixation, 1e-6);
        j["settle_ms"] = summary(&self.settle_us, 1e-3);
        j["pursuit_error_deg"] = summary(&self.pursuit, 1e-6);
        j["goals_unsettled"] = serde_json::json!(self.goals_unsettled);
        j["goals_settled_late"] = serde_json::json!(self.goals_settled_late);
        j["frames_moving_ungated"] = serde_json::json!(self.frames_moving_ungated);
        j["refused_motion_deg"] = serde_json::json!(self.refused_motion_deg);
        j["idle_theta_max_deg"] = serde_json::json!(self.idle_theta_max_deg);
        j["seq_gaps"] = serde_json::json!(self.seq_gaps);
        j["frames_without_truth"] = serde_json::json!(self.no_truth);
        j["settle_within_deg"] = serde_json::json!(SETTLE_DEG);
        stats.extra.insert("gaze".into(), j);
    }
}
