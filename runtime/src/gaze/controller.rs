//! The gaze controller: goals -> validated fixations -> yoked minimum-jerk moves of the drive board.
//!
//! Validation, in order (the first failing check names the refusal; nothing is sent and the eyes hold):
//! finite values and a known kind; a drive board; both eyes homed; the encoder watchdog; then, for a point,
//! in front of both eyes, at least [`GazeConfig::min_distance_m`] from both, each eye's orientation (Listing's
//! law) inside the workspace (pitch and yaw +-[`PITCH_YAW_LIMIT_DEG`], roll +-[`ROLL_LIMIT_DEG`]), and both
//! eyes' calibrated IK (its refusals: near-singular, no convergence).
use abvs_eye::pose::Pose;
use abvs_fk::gaze::{Binocular, Pursuit, Torsion, YokedSaccade};
use abvs_fk::ik::CalibratedIk;
use abvs_fk::model::{FkModel, FkState};
use hdrhistogram::Histogram;
use nalgebra::Vector3;

use super::{GazeConfig, Goal, GoalKind};
use abvs_runtime_core::gaze::{GazeState, Phase, Refusal};
use abvs_runtime_core::source::BoardLink;

/// Largest pitch (alpha) and yaw (gamma) of an eye's orientation (deg, Fick).
pub const PITCH_YAW_LIMIT_DEG: f64 = 30.0;
/// Largest roll (beta) of an eye's orientation (deg, Fick).
pub const ROLL_LIMIT_DEG: f64 = 15.0;
/// Saccades remembered for gating frames processed after them (a frame's exposure is at most a few frames
/// old when the controller sees it).
const SACCADE_HISTORY: usize = 8;

/// The drive board for one step, if the run has one.
pub type BoardRef<'a> = Option<&'a mut (dyn BoardLink + 'static)>;

/// What the controller counted.
#[derive(Debug, Clone)]
pub struct GazeCounts {
    /// Goals taken.
    pub goals: u64,
    /// Goals accepted (moves sent).
    pub accepted: u64,
    /// Refusals by reason ([`Refusal::index`]); a pursuit refused mid-way counts too.
    pub refused: [u64; Refusal::ALL.len()],
    /// Goals whose saccade arrived (encoders at the target).
    pub settled: u64,
    /// Move commands sent (both eyes each).
    pub commands: u64,
    /// Frames gated because their exposure overlapped a commanded saccade.
    pub frames_gated_saccade: u64,
    /// Planned saccade durations (us).
    pub planned_us: Histogram<u64>,
}

impl Default for GazeCounts {
    fn default() -> Self {
        GazeCounts {
            goals: 0,
            accepted: 0,
            refused: [0; Refusal::ALL.len()],
            settled: 0,
            commands: 0,
            frames_gated_saccade: 0,
            planned_us: Histogram::new_with_bounds(1, 60_000_000, 3).expect("valid histogram bounds"),
        }
    }
}

impl GazeCounts {
    /// The statistics JSON's `gaze` section (without the mailbox's counts).
    pub fn json(&self) -> serde_json::Value {
        let refused: serde_json::Map<String, serde_json::Value> =
            Refusal::ALL.iter().map(|r| (r.name().to_string(), serde_json::json!(self.refused[r.index()]))).collect();
        let h = &self.planned_us;
        let ms = |q: f64| {
            if h.is_empty() {
                serde_json::Value::Null
            } else {
                serde_json::json!(h.value_at_quantile(q) as f64 * 1e-3)
            }
        };
        serde_json::json!({
            "goals": self.goals,
            "accepted": self.accepted,
            "refused": refused,
            "settled": self.settled,
            "commands": self.commands,
            "frames_gated_saccade": self.frames_gated_saccade,
            "planned_ms": {"p50": ms(0.5), "max": ms(1.0), "n": h.len()},
        })
    }
}

/// A pursuit under way: the point (mm) from the instant `t0_ns`.
#[derive(Debug, Clone, Copy)]
struct Pursuing {
    pursuit: Pursuit,
    t0_ns: i64,
}

/// See the module doc.
pub struct GazeController {
    cfg: GazeConfig,
    models: [FkModel; 2],
    /// The IK's motion history of each eye (initialised at the links' angles when the first goal comes).
    st: Option<[FkState; 2]>,
    /// T_lH^rH (mm).
    left_to_right_mm: Pose,
    gravity: [f64; 3],
    goal_id: u64,
    phase: Phase,
    reason: Option<Refusal>,
    commanded_m: [f64; 3],
    planned_ms: f64,
    /// The link angles last commanded (deg, homed).
    target_deg: [[f64; 3]; 2],
    move_end_ns: i64,
    pursuing: Option<Pursuing>,
    /// Frame interval estimate (ns): a pursuit step's duration.
    interval_ns: i64,
    last_now_ns: Option<i64>,
    /// Commanded saccades [start, end + margin] (ns), a ring.
    saccades: [(i64, i64); SACCADE_HISTORY],
    next_saccade: usize,
    /// What it counted.
    pub counts: GazeCounts,
}

fn finite(v: &[f64; 3]) -> bool {
    v.iter().all(|x| x.is_finite())
}

fn in_workspace(f: &[f64; 3]) -> bool {
    f[0].abs() <= PITCH_YAW_LIMIT_DEG && f[2].abs() <= PITCH_YAW_LIMIT_DEG && f[1].abs() <= ROLL_LIMIT_DEG
}

/// The refusal of a fixation the calibrated IK (or its aiming) refused.
fn classify(e: &abvs_fk::FkError) -> Refusal {
    let m = e.to_string();
    if m.contains("near-singular") {
        Refusal::NearSingular
    } else if m.contains("behind the eye") {
        Refusal::BehindEyes
    } else if m.contains("from the optical centre") {
        Refusal::TooNear
    } else {
        Refusal::Unreachable
    }
}

impl GazeController {
    /// A controller for both eyes' IK models (left, right), the stereo extrinsic at home T_lH^rH (translation
    /// in metres, as the runtime holds it) and the gravity direction the FK is evaluated with.
    pub fn new(cfg: GazeConfig, models: [FkModel; 2], home_left_to_right_m: &Pose, gravity: [f64; 3]) -> Self {
        GazeController {
            cfg,
            models,
            st: None,
            left_to_right_mm: Pose::new(home_left_to_right_m.r, home_left_to_right_m.t * 1000.0),
            gravity,
            goal_id: 0,
            phase: Phase::Idle,
            reason: None,
            commanded_m: [f64::NAN; 3],
            planned_ms: 0.0,
            target_deg: [[0.0; 3]; 2],
            move_end_ns: i64::MIN,
            pursuing: None,
            interval_ns: 33_000_000,
            last_now_ns: None,
            saccades: [(i64::MAX, i64::MIN); SACCADE_HISTORY],
            next_saccade: 0,
            counts: GazeCounts::default(),
        }
    }

    /// The settings.
    pub fn config(&self) -> &GazeConfig {
        &self.cfg
    }

    /// One frame: takes `goal` (if any) at `now_ns` (CLOCK_MONOTONIC) with the links at `theta` (deg, homed,
    /// the frame's), steps a pursuit, and notices a saccade's arrival. Allocates nothing without a goal.
    pub fn step(&mut self, now_ns: i64, theta: &[[f64; 3]; 2], goal: Option<Goal>, board: BoardRef<'_>) {
        if let Some(last) = self.last_now_ns {
            if now_ns > last {
                self.interval_ns = (now_ns - last).clamp(5_000_000, 100_000_000);
            }
        }
        self.last_now_ns = Some(now_ns);
        match goal {
            Some(g) => self.take(g, now_ns, theta, board),
            None if self.pursuing.is_some() => self.pursue_step(now_ns, theta, board),
            None => {}
        }
        if self.phase == Phase::Saccade && now_ns >= self.move_end_ns {
            let tol = self.cfg.settle_tol_deg;
            let at = (0..2).all(|e| (0..3).all(|i| (theta[e][i] - self.target_deg[e][i]).abs() <= tol));
            if at {
                self.phase = Phase::Settled;
                self.counts.settled += 1;
            }
        }
    }

    /// The state after the last step, for frame `seq` (measured fields NaN: the stage fills them).
    pub fn state(&self, seq: u64) -> GazeState {
        GazeState {
            seq,
            goal_id: self.goal_id,
            phase: self.phase,
            reason: self.reason,
            commanded_m: self.commanded_m,
            planned_ms: self.planned_ms,
            ..GazeState::default()
        }
    }

    /// Whether `[a_ns, b_ns]` (a frame's exposure) overlaps a commanded saccade.
    pub fn overlaps_saccade(&self, a_ns: i64, b_ns: i64) -> bool {
        self.saccades.iter().any(|&(s, e)| a_ns <= e && s <= b_ns)
    }

    fn refuse(&mut self, r: Refusal) {
        self.phase = Phase::Refused;
        self.reason = Some(r);
        self.commanded_m = [f64::NAN; 3];
        self.planned_ms = 0.0;
        self.pursuing = None;
        self.counts.refused[r.index()] += 1;
    }

    /// The board's readiness for a new command.
    fn ready(&self, now_ns: i64, board: &BoardRef<'_>) -> Result<(), Refusal> {
        let b = board.as_ref().ok_or(Refusal::NoBoard)?;
        b.home_counts().ok_or(Refusal::NotHomed)?;
        let silent = b.last_record_ns().is_none_or(|t| (now_ns - t) as f64 * 1e-6 > self.cfg.watchdog_ms);
        if silent {
            return Err(Refusal::EncodersSilent);
        }
        Ok(())
    }

    /// The IK's states, at the links' angles on first use.
    fn states(&mut self, theta: &[[f64; 3]; 2]) -> [FkState; 2] {
        if self.st.is_none() {
            let g = self.gravity;
            let st = [0, 1].map(|e| {
                let mut s = self.models[e].state();
                // a reading the model cannot evaluate leaves the history at home: the IK starts from there
                let _ = self.models[e].eval(&mut s, &theta[e], g);
                s
            });
            self.st = Some(st);
        }
        self.st.clone().expect("just set")
    }

    /// Both eyes' link angles fixating `point_m`, and the states advanced by the move (not committed).
    fn fixate(&mut self, point_m: [f64; 3], theta: &[[f64; 3]; 2]) -> Result<([[f64; 3]; 2], [FkState; 2]), Refusal> {
        if !finite(&point_m) {
            return Err(Refusal::NonFinite);
        }
        let pl = Vector3::from(point_m) * 1000.0;
        let pr = self.left_to_right_mm.r * pl + self.left_to_right_mm.t;
        if pl.z <= 0.0 || pr.z <= 0.0 {
            return Err(Refusal::BehindEyes);
        }
        if pl.norm().min(pr.norm()) < self.cfg.min_distance_m * 1000.0 {
            return Err(Refusal::TooNear);
        }
        for p in [pl, pr] {
            if !in_workspace(&Torsion::Listing.orientation_deg(&p.normalize())) {
                return Err(Refusal::OutsideWorkspace);
            }
        }
        let [mut a, mut b] = self.states(theta);
        let bino = Binocular {
            left: CalibratedIk::new(&self.models[0]),
            right: CalibratedIk::new(&self.models[1]),
            left_to_right: self.left_to_right_mm,
            torsion: Torsion::Listing,
        };
        let g = self.gravity;
        let f = bino.fixate_and_move([&mut a, &mut b], [pl.x, pl.y, pl.z], [g; 2]).map_err(|e| classify(&e))?;
        if !in_workspace(&f.left.ik.target_deg) || !in_workspace(&f.right.ik.target_deg) {
            return Err(Refusal::OutsideWorkspace);
        }
        Ok(([f.left.ik.theta_deg, f.right.ik.theta_deg], [a, b]))
    }

    /// Link angles for a goal that needs no IK (home, hold), with the states advanced to them.
    fn direct(&mut self, to: [[f64; 3]; 2], theta: &[[f64; 3]; 2]) -> ([[f64; 3]; 2], [FkState; 2]) {
        let mut st = self.states(theta);
        for e in 0..2 {
            let _ = self.models[e].eval(&mut st[e], &to[e], self.gravity);
        }
        (to, st)
    }

    fn take(&mut self, g: Goal, now_ns: i64, theta: &[[f64; 3]; 2], mut board: BoardRef<'_>) {
        self.counts.goals += 1;
        self.goal_id = g.id;
        self.pursuing = None;
        if !finite(&g.point_m) || !finite(&g.velocity_m_s) {
            return self.refuse(Refusal::NonFinite);
        }
        if let Err(r) = self.ready(now_ns, &board) {
            return self.refuse(r);
        }
        let lead_s = self.interval_ns as f64 * 1e-9;
        let solved = match g.kind {
            GoalKind::LookAt => self.fixate(g.point_m, theta).map(|s| (s, g.point_m)),
            GoalKind::Pursue => {
                let p =
                    Pursuit { point_mm: g.point_m.map(|v| v * 1e3), velocity_mm_s: g.velocity_m_s.map(|v| v * 1e3) };
                // the first move lands on the point one frame ahead, where the pursuit steps take over
                let ahead = p.point_at(lead_s).map(|v| v * 1e-3);
                self.fixate(ahead, theta).map(|s| {
                    self.pursuing = Some(Pursuing { pursuit: p, t0_ns: now_ns });
                    (s, g.point_m)
                })
            }
            GoalKind::Home => Ok((self.direct([[0.0; 3]; 2], theta), [f64::NAN; 3])),
            GoalKind::Hold => Ok((self.direct(*theta, theta), [f64::NAN; 3])),
        };
        let ((to, st), commanded) = match solved {
            Ok(s) => s,
            Err(r) => return self.refuse(r),
        };
        let plan = YokedSaccade::plan(*theta, to, self.cfg.peak_deg_s);
        let pursuit = g.kind == GoalKind::Pursue;
        let duration_us = if pursuit { plan.duration_us.max((lead_s * 1e6) as u32) } else { plan.duration_us };
        if let Err(r) = self.send(&mut board, &plan, duration_us) {
            return self.refuse(r);
        }
        self.st = Some(st);
        self.counts.accepted += 1;
        self.reason = None;
        self.commanded_m = commanded;
        self.target_deg = plan.to_deg;
        self.move_end_ns = now_ns + i64::from(duration_us) * 1000;
        self.planned_ms = f64::from(plan.duration_us) * 1e-3;
        self.counts.planned_us.saturating_record(u64::from(plan.duration_us).max(1));
        self.phase = if pursuit { Phase::Pursuit } else { Phase::Saccade };
        let margin = (self.cfg.gate_margin_ms * 1e6) as i64;
        self.saccades[self.next_saccade] = (now_ns, self.move_end_ns + margin);
        self.next_saccade = (self.next_saccade + 1) % SACCADE_HISTORY;
    }

    fn send(&mut self, board: &mut BoardRef<'_>, plan: &YokedSaccade, duration_us: u32) -> Result<(), Refusal> {
        let b = board.as_mut().ok_or(Refusal::NoBoard)?;
        b.send_move(plan.target_counts, duration_us).map_err(|e| {
            log::warn!("gaze: {e}");
            Refusal::SendFailed
        })?;
        self.counts.commands += 1;
        Ok(())
    }

    /// A pursuit's frame: the point one frame ahead, reached over that frame.
    fn pursue_step(&mut self, now_ns: i64, theta: &[[f64; 3]; 2], mut board: BoardRef<'_>) {
        let Some(p) = self.pursuing else { return };
        if let Err(r) = self.ready(now_ns, &board) {
            return self.refuse(r);
        }
        let t_s = (now_ns - p.t0_ns) as f64 * 1e-9;
        let lead_s = self.interval_ns as f64 * 1e-9;
        let ahead = p.pursuit.point_at(t_s + lead_s).map(|v| v * 1e-3);
        let (to, st) = match self.fixate(ahead, theta) {
            Ok(s) => s,
            Err(r) => return self.refuse(r),
        };
        let plan = YokedSaccade::plan(*theta, to, self.cfg.peak_deg_s);
        let duration_us = plan.duration_us.max((lead_s * 1e6) as u32);
        if let Err(r) = self.send(&mut board, &plan, duration_us) {
            return self.refuse(r);
        }
        self.st = Some(st);
        self.target_deg = plan.to_deg;
        self.move_end_ns = now_ns + i64::from(duration_us) * 1000;
        self.commanded_m = p.pursuit.point_at(t_s).map(|v| v * 1e-3);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The calibrated IK's refusals (abvs_fk::ik, abvs_fk::gaze) reach the state by name: near a singularity,
    /// behind the eye, too near, and anything else as unreachable.
    #[test]
    fn the_iks_refusals_are_named() {
        let e = |why: &str| abvs_fk::FkError::Unreachable { target_deg: [1.0, 2.0, 3.0], why: why.into() };
        let cases = [
            (
                "near-singular: the model's d(orientation)/d(theta) has inverse condition number 0.0010",
                Refusal::NearSingular,
            ),
            ("no nominal IK to start from (unreachable or near-singular): out of range", Refusal::NearSingular),
            ("behind the eye (z <= 0 in its home camera frame)", Refusal::BehindEyes),
            ("42.0 mm from the optical centre (at least 50 mm)", Refusal::TooNear),
            ("no convergence in 40 iterations (residual 0.3 deg)", Refusal::Unreachable),
        ];
        for (why, want) in cases {
            assert_eq!(classify(&e(why)), want, "{why}");
        }
    }
}
