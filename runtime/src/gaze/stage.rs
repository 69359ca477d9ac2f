//! The gaze stage: the controller once per frame, after kinematics (which solved the frame's poses). It
//! takes the newest goal, measures where the eyes look, gates frames exposed during a commanded saccade, and
//! writes the frame's [`GazeState`] into [`abvs_runtime_core::messages::FrameMotion::gaze`] (and the mailbox's latest).
use std::sync::Arc;

use abvs_eye::Pose;
use nalgebra::Vector3;

use super::controller::GazeController;
use super::limit::GoalGate;
use super::Mailbox;
use abvs_runtime_core::error::Result;
use abvs_runtime_core::gaze::GazeState;
use abvs_runtime_core::messages::{monotonic_ns, StereoPose, Work};
use abvs_runtime_core::params::RateLimit;
use abvs_runtime_core::source::BoardLink;
use abvs_runtime_core::stage::{Stage, StageContext};
use abvs_runtime_core::stats::RunStats;

/// See the module doc.
pub struct GazeStage {
    ctl: GazeController,
    mailbox: Arc<Mailbox>,
    board: Option<Box<dyn BoardLink>>,
    /// T_lH^rH (m).
    home_left_to_right: Pose,
    /// The rate limit and the counts per source.
    gate: GoalGate,
    /// The source of the goal last taken.
    source: Option<super::GoalSource>,
    /// This stage's own CPU time (its thread's clock around `process`, ns) and the frames it ran on: what the
    /// gaze service costs the rectify lane (`gaze_cpu` in the statistics).
    cpu_ns: i64,
    frames: u64,
}

impl GazeStage {
    /// The stage for a controller, the mailbox the goals come through and the home extrinsic T_lH^rH (m).
    pub fn new(ctl: GazeController, mailbox: Arc<Mailbox>, home_left_to_right: Pose) -> GazeStage {
        GazeStage {
            ctl,
            mailbox,
            board: None,
            home_left_to_right,
            gate: GoalGate::new(RateLimit::default()),
            source: None,
            cpu_ns: 0,
            frames: 0,
        }
    }

    /// The same with the rate limit `limit` on the goals executed.
    pub fn with_rate_limit(mut self, limit: RateLimit) -> GazeStage {
        self.gate = GoalGate::new(limit);
        self
    }
}

/// Where both optical axes come closest (m, left home camera frame: the midpoint of the shortest segment
/// between them) and its distance from the midpoint of both optical centres; NaN where the axes are parallel
/// or meet behind an eye.
pub fn measured_fixation(pose: &StereoPose, home_left_to_right: &Pose) -> ([f64; 3], f64) {
    let (o1, d1) = (pose.rel_left.t, pose.rel_left.r * Vector3::z());
    // the right eye's axis in the left home frame: x_l = R^T (x_r - t)
    let h = home_left_to_right;
    let o2 = h.r.transpose() * (pose.rel_right.t - h.t);
    let d2 = h.r.transpose() * (pose.rel_right.r * Vector3::z());
    let w0 = o1 - o2;
    let (b, d, e) = (d1.dot(&d2), d1.dot(&w0), d2.dot(&w0));
    let denom = 1.0 - b * b;
    let nan = ([f64::NAN; 3], f64::NAN);
    if !(denom > 1e-12) {
        return nan;
    }
    let (s, t) = ((b * e - d) / denom, (e - b * d) / denom);
    if !(s > 0.0 && t > 0.0) {
        return nan;
    }
    let p = (o1 + d1 * s + o2 + d2 * t) * 0.5;
    ([p.x, p.y, p.z], (p - (o1 + o2) * 0.5).norm())
}

impl Stage for GazeStage {
    fn name(&self) -> &'static str {
        "gaze"
    }

    fn start(&mut self, ctx: &mut StageContext) -> Result<()> {
        self.board = ctx.board.take();
        Ok(())
    }

    fn process(&mut self, w: &mut Work) -> Result<()> {
        let t0 = abvs_runtime_core::cpu::thread_cpu_ns();
        self.step(w);
        self.cpu_ns += abvs_runtime_core::cpu::thread_cpu_ns() - t0;
        self.frames += 1;
        Ok(())
    }

    fn failure(&self, _e: &abvs_runtime_core::error::RuntimeError) -> &'static str {
        "gaze failed"
    }

    fn finish(&mut self, stats: &mut RunStats) {
        let mut j = self.ctl.counts.json();
        let (posted, superseded) = self.mailbox.counts();
        j["posted"] = serde_json::json!(posted);
        j["superseded"] = serde_json::json!(superseded);
        j["peak_deg_s"] = serde_json::json!(self.ctl.config().peak_deg_s);
        j["min_distance_m"] = serde_json::json!(self.ctl.config().min_distance_m);
        (j["sources"], j["rate_limit"]) = self.gate.json(&self.mailbox);
        stats.extra.insert("gaze".into(), j);
        // apart from `gaze`: CPU time differs run to run, the gaze statistics of a simulated run do not
        let us = self.cpu_ns as f64 * 1e-3 / self.frames.max(1) as f64;
        stats.extra.insert("gaze_cpu".into(), serde_json::json!({"frames": self.frames, "stage_us_per_frame": us}));
    }
}

impl GazeStage {
    /// One frame: the goal, the controller, the measured fixation, the saccade gate, the state.
    fn step(&mut self, w: &mut Work) {
        let m = &w.motion;
        let first = m.t_start_ns[0].min(m.t_start_ns[1]);
        let last = m.t_start_ns[0].max(m.t_start_ns[1]) + m.readout_ns + m.exposure_ns;
        // a simulated head runs in virtual time: its board says when the controller acts on this frame
        let now = self.board.as_ref().and_then(|b| b.virtual_now_ns(last)).unwrap_or_else(monotonic_ns);
        let goal = self.gate.next(&self.mailbox, now);
        let refused_before: u64 = self.ctl.counts.refused.iter().sum();
        self.ctl.step(now, &w.theta, goal.map(|g| g.0), self.board.as_deref_mut());
        if let Some((_, source)) = goal {
            if self.ctl.counts.refused.iter().sum::<u64>() > refused_before {
                self.gate.refused(source);
            }
            self.source = Some(source);
        }
        let mut s: GazeState = self.ctl.state(w.seq);
        s.source = self.source;
        s.goal_waiting = self.gate.waiting();
        if let Some(pose) = &w.pose {
            (s.measured_m, s.vergence_m) = measured_fixation(pose, &self.home_left_to_right);
        }
        if self.ctl.overlaps_saccade(first, last) {
            // known from the plan, before the encoders show the speed: the speed gate stays as it was
            w.motion.gated = true;
            s.gated_saccade = true;
            self.ctl.counts.frames_gated_saccade += 1;
        }
        w.motion.gaze = s;
        self.mailbox.set_state(s);
        if let Some(b) = self.board.as_mut() {
            b.frame_done(w.seq);
        }
    }
}
