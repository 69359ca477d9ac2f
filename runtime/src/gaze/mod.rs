//! Pointing the eyes: gaze goals from the robot's processes become moves of the drive board.
//!
//! - Goals ([`Goal`]): look at a point, pursue a moving point, hold, go home; each has an id. Points are in
//!   metres in the left home camera frame (conventions.md), velocities in m/s.
//! - [`GazeHandle`] posts goals into a latest-wins mailbox ([`Mailbox`]): a flood of goals never queues, the
//!   newest replaces one not yet taken (counted as superseded). The controller takes it at the next frame.
//! - [`controller::GazeController`] validates a goal (refusals by name, [`Refusal`], counted; the eyes hold
//!   on a refusal: nothing is sent), solves both eyes' calibrated IK for the fixation (Listing's law,
//!   abvs_fk::gaze), and plans a yoked minimum-jerk saccade at the peak link speed, or re-solves the
//!   fixation each frame for a pursued point.
//! - [`stage::GazeStage`] runs it once per frame after kinematics: it measures where the eyes look (the
//!   closest approach of both optical axes from the encoders and calibrated FK), gates the frames whose
//!   exposure overlaps a commanded saccade (reason "saccade", before the encoders show the speed), and
//!   writes the frame's [`GazeState`] (in [`crate::messages::FrameMotion::gaze`]).
//!
//! # Phases of [`GazeState`]
//! - `idle`: no goal taken yet;
//! - `saccade`: a saccade (or a move home / to hold) is under way, until its planned duration has passed
//!   and the encoders read the target link angles (within [`GazeConfig::settle_tol_deg`]);
//! - `settled`: the eyes sit at the goal;
//! - `pursuit`: the eyes follow a moving point (re-solved each frame);
//! - `refused`: the latest goal was refused ([`GazeState::reason`]); the eyes hold (nothing was sent).
pub mod controller;
pub mod limit;
pub mod stage;

pub use limit::{GoalSource, RateLimit};

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

/// The phase of the gaze at a frame; see the module doc.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(u8)]
pub enum Phase {
    /// No goal yet.
    #[default]
    Idle = 0,
    /// Moving to a fixed target.
    Saccade = 1,
    /// Following a moving point.
    Pursuit = 2,
    /// At the goal.
    Settled = 3,
    /// The latest goal was refused.
    Refused = 4,
}

impl Phase {
    /// Its name in the state and the statistics.
    pub fn name(self) -> &'static str {
        match self {
            Phase::Idle => "idle",
            Phase::Saccade => "saccade",
            Phase::Pursuit => "pursuit",
            Phase::Settled => "settled",
            Phase::Refused => "refused",
        }
    }
}

/// Why a goal was refused (the eyes hold). The wire value is the index in [`Refusal::ALL`] plus one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Refusal {
    /// A NaN or infinite coordinate, or an unknown kind.
    NonFinite = 1,
    /// The point is behind an eye (z <= 0 in its home camera frame).
    BehindEyes = 2,
    /// The point is nearer than [`GazeConfig::min_distance_m`] to an eye.
    TooNear = 3,
    /// An eye's orientation would leave the workspace (pitch, yaw +-30 deg, roll +-15 deg).
    OutsideWorkspace = 4,
    /// The calibrated IK refuses: near a singularity of the mechanism.
    NearSingular = 5,
    /// The calibrated IK refuses otherwise (no convergence, out of the working mode).
    Unreachable = 6,
    /// The drive board has not homed both eyes.
    NotHomed = 7,
    /// No encoder record for longer than [`GazeConfig::watchdog_ms`] (no new command until it resumes).
    EncodersSilent = 8,
    /// The run has no drive board (a replay).
    NoBoard = 9,
    /// The command could not be written to the board.
    SendFailed = 10,
}

impl Refusal {
    /// Every reason, in wire order.
    pub const ALL: [Refusal; 10] = [
        Refusal::NonFinite,
        Refusal::BehindEyes,
        Refusal::TooNear,
        Refusal::OutsideWorkspace,
        Refusal::NearSingular,
        Refusal::Unreachable,
        Refusal::NotHomed,
        Refusal::EncodersSilent,
        Refusal::NoBoard,
        Refusal::SendFailed,
    ];

    /// Its name in the state and the statistics.
    pub fn name(self) -> &'static str {
        match self {
            Refusal::NonFinite => "non_finite",
            Refusal::BehindEyes => "behind_eyes",
            Refusal::TooNear => "too_near",
            Refusal::OutsideWorkspace => "outside_workspace",
            Refusal::NearSingular => "near_singular",
            Refusal::Unreachable => "unreachable",
            Refusal::NotHomed => "not_homed",
            Refusal::EncodersSilent => "encoders_silent",
            Refusal::NoBoard => "no_board",
            Refusal::SendFailed => "send_failed",
        }
    }

    /// Index in [`Refusal::ALL`].
    pub fn index(self) -> usize {
        self as usize - 1
    }
}

/// The gaze at one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GazeState {
    /// The frame's pipeline sequence number.
    pub seq: u64,
    /// The goal this state is about (0: none taken yet).
    pub goal_id: u64,
    /// See the module doc.
    pub phase: Phase,
    /// Why the goal was refused (phase `refused` only).
    pub reason: Option<Refusal>,
    /// The fixation point commanded (m, left home camera frame; the pursued point at this frame); NaN when
    /// none (idle, home, hold, refused).
    pub commanded_m: [f64; 3],
    /// Where the eyes look at this frame: the midpoint of the closest approach of both optical axes, from
    /// the encoders and calibrated FK (m, left home camera frame); NaN when the axes do not converge in
    /// front of the eyes (parallel or diverging).
    pub measured_m: [f64; 3],
    /// Distance from the midpoint of both optical centres to the measured fixation point (m); NaN as above.
    pub vergence_m: f64,
    /// The planned duration of the goal's saccade (ms; 0 without one).
    pub planned_ms: f64,
    /// The frame's exposure overlaps a commanded saccade: gated with reason "saccade".
    pub gated_saccade: bool,
    /// Where the goal of `goal_id` came from (`None` before the first).
    pub source: Option<GoalSource>,
    /// A newer goal waits for the rate limit ([`RateLimit`]): it is taken at a later frame unless a newer one
    /// replaces it.
    pub goal_waiting: bool,
}

impl Default for GazeState {
    fn default() -> Self {
        GazeState {
            seq: 0,
            goal_id: 0,
            phase: Phase::Idle,
            reason: None,
            commanded_m: [f64::NAN; 3],
            measured_m: [f64::NAN; 3],
            vergence_m: f64::NAN,
            planned_ms: 0.0,
            gated_saccade: false,
            source: None,
            goal_waiting: false,
        }
    }
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
