//! The gaze's messages: the state of the gaze at each frame ([`GazeState`], carried in
//! [`crate::messages::FrameMotion::gaze`] and published by the bridges), its phases, the reasons a goal is
//! refused and where goals come from. The controller that writes them is the runtime's `gaze` module.
//!
//! # Phases
//! - `idle`: no goal taken yet;
//! - `saccade`: a saccade (or a move home / to hold) is under way, until its planned duration has passed
//!   and the encoders read the target link angles;
//! - `settled`: the eyes sit at the goal;
//! - `pursuit`: the eyes follow a moving point (re-solved each frame);
//! - `refused`: the latest goal was refused ([`GazeState::reason`]); the eyes hold (nothing was sent).
use serde::{Deserialize, Serialize};

/// Where a goal came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[repr(u8)]
pub enum GoalSource {
    /// The running runtime's `GazeHandle` (the robot's own process).
    Rust = 1,
    /// The iceoryx2 service `{prefix}/gaze/goal` (a process on this machine).
    Iceoryx2 = 2,
    /// `/abvs/gaze/goal` over Zenoh (another machine; off unless `[bridges.zenoh] accept_gaze_goals`).
    Zenoh = 3,
}

impl GoalSource {
    /// Every source, in wire order.
    pub const ALL: [GoalSource; 3] = [GoalSource::Rust, GoalSource::Iceoryx2, GoalSource::Zenoh];

    /// Its name in the statistics and the Zenoh state.
    pub fn name(self) -> &'static str {
        match self {
            GoalSource::Rust => "rust",
            GoalSource::Iceoryx2 => "iceoryx2",
            GoalSource::Zenoh => "zenoh",
        }
    }

    /// Index in [`GoalSource::ALL`].
    pub fn index(self) -> usize {
        self as usize - 1
    }
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
    /// The point is nearer than the gaze controller's `min_distance_m` to an eye.
    TooNear = 3,
    /// An eye's orientation would leave the workspace (pitch, yaw +-30 deg, roll +-15 deg).
    OutsideWorkspace = 4,
    /// The calibrated IK refuses: near a singularity of the mechanism.
    NearSingular = 5,
    /// The calibrated IK refuses otherwise (no convergence, out of the working mode).
    Unreachable = 6,
    /// The drive board has not homed both eyes.
    NotHomed = 7,
    /// No encoder record for longer than the gaze controller's `watchdog_ms` (no new command until it resumes).
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
    /// A newer goal waits for the rate limit ([`crate::params::RateLimit`]): it is taken at a later frame unless a newer one
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
