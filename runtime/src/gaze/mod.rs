//! Pointing the eyes: gaze goals from the robot's processes become moves of the drive board.
//!
//! - Goals ([`Goal`]): look at a point, pursue a moving point, hold, go home; each has an id. Points are in
//!   metres in the left home camera frame (conventions.md), velocities in m/s.
//! - [`GazeHandle`] posts goals into a latest-wins mailbox ([`Mailbox`]): a flood of goals never queues, the
//!   newest replaces one not yet taken (counted as superseded). The controller takes it at the next frame.
//! - [`controller::GazeController`] validates a goal (refusals by name, [`abvs_runtime_core::gaze::Refusal`], counted; the eyes hold
//!   on a refusal: nothing is sent), solves both eyes' calibrated IK for the fixation (Listing's law,
//!   abvs_fk::gaze), and plans a yoked minimum-jerk saccade at the peak link speed, or re-solves the
//!   fixation each frame for a pursued point.
//! - [`stage::GazeStage`] runs it once per frame after kinematics: it measures where the eyes look (the
//!   closest approach of both optical axes from the encoders and calibrated FK), gates the frames whose
//!   exposure overlaps a commanded saccade (reason "saccade", before the encoders show the speed), and
//!   writes the frame's [`GazeState`] (in [`abvs_runtime_core::messages::FrameMotion::gaze`]).
//! - [`direct`]: saccades straight on the drive board's link, without the pipeline (`abvs gaze saccade`).
//!
//! # Phases of [`GazeState`]
//! - `idle`: no goal taken yet;
//! - `saccade`: a saccade (or a move home / to hold) is under way, until its planned duration has passed
//!   and the encoders read the target link angles (within [`GazeConfig::settle_tol_deg`]);
//! - `settled`: the eyes sit at the goal;
//! - `pursuit`: the eyes follow a moving point (re-solved each frame);
//! - `refused`: the latest goal was refused ([`GazeState::reason`]); the eyes hold (nothing was sent).
pub mod controller;
pub mod direct;
pub mod limit;
pub mod stage;

use abvs_runtime_core::gaze::{GazeState, GoalSource};

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

/// What a goal asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum GoalKind {
    /// Both eyes fixate the point (a saccade, then hold).
    LookAt = 1,
    /// Both eyes follow the point moving at the velocity from the instant the goal is taken.
    Pursue = 2,
    /// Stop where the eyes are (ends a pursuit).
    Hold = 3,
    /// Both eyes to home (all link angles 0).
    Home = 4,
}

impl GoalKind {
    /// The kind of a wire value (the iceoryx2 goal's `kind`).
    pub fn from_u8(v: u8) -> Option<GoalKind> {
        match v {
            1 => Some(GoalKind::LookAt),
            2 => Some(GoalKind::Pursue),
            3 => Some(GoalKind::Hold),
            4 => Some(GoalKind::Home),
            _ => None,
        }
    }
}

/// One gaze goal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Goal {
    /// The goal's id (non-zero), reported back in every state until the next goal is taken.
    pub id: u64,
    /// What to do.
    pub kind: GoalKind,
    /// The point (m, left home camera frame); look_at and pursue.
    pub point_m: [f64; 3],
    /// The point's velocity (m/s, left home camera frame); pursue.
    pub velocity_m_s: [f64; 3],
}

/// Settings of the gaze controller.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GazeConfig {
    /// Peak link speed of a saccade (deg/s; the paper's 1561).
    pub peak_deg_s: f64,
    /// Points nearer than this to either eye's home optical centre are refused (m). 0.1 m: nearer, the
    /// vergence exceeds the yaw workspace for the 65 mm baseline, and the cameras cannot focus there.
    pub min_distance_m: f64,
    /// The encoder stream counts as silent after this long without a record (ms).
    pub watchdog_ms: f64,
    /// Settled when every link of both eyes reads within this of its target (deg; one count is 0.0039).
    pub settle_tol_deg: f64,
    /// A frame is gated when its exposure overlaps a commanded saccade widened by this at its end (ms): the
    /// command's time on the wire and the servo's lag behind the profile.
    pub gate_margin_ms: f64,
}

impl Default for GazeConfig {
    fn default() -> Self {
        GazeConfig {
            peak_deg_s: abvs_eye::saccade::PEAK_SPEED_DEG_S,
            min_distance_m: 0.1,
            watchdog_ms: 100.0,
            settle_tol_deg: 0.02,
            gate_margin_ms: 5.0,
        }
    }
}

/// The latest-wins goal mailbox between the robot's processes and the controller: one slot; a goal posted
/// before the previous one was taken replaces it (counted). Taking checks an atomic flag first, so a frame
/// without a new goal takes no lock.
#[derive(Debug, Default)]
pub struct Mailbox {
    slot: Mutex<Option<(Goal, GoalSource)>>,
    pending: AtomicBool,
    next_id: AtomicU64,
    posted: AtomicU64,
    superseded: AtomicU64,
    /// Posted and superseded per [`GoalSource`] (its index).
    by_source: [[AtomicU64; 2]; GoalSource::ALL.len()],
    latest: Mutex<Option<GazeState>>,
}

impl Mailbox {
    /// Posts `goal` from the Rust handle (replacing one not yet taken).
    pub fn post(&self, goal: Goal) {
        self.post_from(goal, GoalSource::Rust)
    }

    /// Posts `goal` that came from `source` (replacing one not yet taken; the replaced one is counted as
    /// superseded under its own source).
    pub fn post_from(&self, goal: Goal, source: GoalSource) {
        let mut s = self.slot.lock().expect("gaze mailbox");
        if let Some((_, old)) = s.replace((goal, source)) {
            self.superseded.fetch_add(1, Ordering::Relaxed);
            self.by_source[old.index()][1].fetch_add(1, Ordering::Relaxed);
        }
        self.posted.fetch_add(1, Ordering::Relaxed);
        self.by_source[source.index()][0].fetch_add(1, Ordering::Relaxed);
        self.pending.store(true, Ordering::Release);
    }

    /// The newest goal not yet taken.
    pub fn take(&self) -> Option<Goal> {
        self.take_from().map(|(g, _)| g)
    }

    /// The newest goal not yet taken, and where it came from.
    pub fn take_from(&self) -> Option<(Goal, GoalSource)> {
        if !self.pending.swap(false, Ordering::Acquire) {
            return None;
        }
        self.slot.lock().expect("gaze mailbox").take()
    }

    /// Goals posted by `source`, and those of them replaced before the controller took them.
    pub fn counts_from(&self, source: GoalSource) -> (u64, u64) {
        let c = &self.by_source[source.index()];
        (c[0].load(Ordering::Relaxed), c[1].load(Ordering::Relaxed))
    }

    /// A fresh goal id (ids of the Rust handle; a process on iceoryx2 chooses its own).
    pub fn next_id(&self) -> u64 {
        self.next_id.fetch_add(1, Ordering::Relaxed) + 1
    }

    /// Goals posted, and those replaced before the controller took them.
    pub fn counts(&self) -> (u64, u64) {
        (self.posted.load(Ordering::Relaxed), self.superseded.load(Ordering::Relaxed))
    }

    /// Records the state of the frame just processed.
    pub fn set_state(&self, s: GazeState) {
        *self.latest.lock().expect("gaze state") = Some(s);
    }

    /// The state of the latest frame (`None` before the first).
    pub fn state(&self) -> Option<GazeState> {
        *self.latest.lock().expect("gaze state")
    }
}

/// Points the eyes of a running runtime ([`crate::runtime::RuntimeHandle::gaze`]); cheap to clone, usable
/// from any thread. Each call posts a goal and returns its id; the frame states report it.
#[derive(Debug, Clone)]
pub struct GazeHandle {
    mailbox: Arc<Mailbox>,
}

impl GazeHandle {
    /// A handle on `mailbox`.
    pub fn new(mailbox: Arc<Mailbox>) -> GazeHandle {
        GazeHandle { mailbox }
    }

    fn post(&self, kind: GoalKind, point_m: [f64; 3], velocity_m_s: [f64; 3]) -> u64 {
        let id = self.mailbox.next_id();
        self.mailbox.post(Goal { id, kind, point_m, velocity_m_s });
        id
    }

    /// Both eyes fixate `point_m` (m, left home camera frame).
    pub fn look_at(&self, point_m: [f64; 3]) -> u64 {
        self.post(GoalKind::LookAt, point_m, [0.0; 3])
    }

    /// Both eyes follow a point at `point_m` now, moving at `velocity_m_s` (m/s).
    pub fn pursue(&self, point_m: [f64; 3], velocity_m_s: [f64; 3]) -> u64 {
        self.post(GoalKind::Pursue, point_m, velocity_m_s)
    }

    /// Stop where the eyes are.
    pub fn hold(&self) -> u64 {
        self.post(GoalKind::Hold, [0.0; 3], [0.0; 3])
    }

    /// Both eyes home.
    pub fn home(&self) -> u64 {
        self.post(GoalKind::Home, [0.0; 3], [0.0; 3])
    }

    /// The state of the latest frame processed (`None` before the first).
    pub fn state(&self) -> Option<GazeState> {
        self.mailbox.state()
    }

    /// The mailbox (for a bridge that posts goals of its own ids).
    pub fn mailbox(&self) -> &Arc<Mailbox> {
        &self.mailbox
    }
}
