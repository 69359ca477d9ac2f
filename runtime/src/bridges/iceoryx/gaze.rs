//! Gaze goals in and gaze states out over iceoryx2 (the Python client: `abvs_iceoryx2.Gaze`).
//!
//! | service | payload | who publishes | settings |
//! | --- | --- | --- | --- |
//! | `{prefix}/gaze/goal` | [`GazeGoalWire`] | any process (up to [`GOAL_PUBLISHERS`]) | subscriber buffer [`GOAL_BUFFER`], no history |
//! | `{prefix}/gaze/state` | [`GazeStateWire`], once per published frame | the runtime | history 1, subscriber buffer 2 |
//!
//! Both use safe overflow (a full buffer drops its oldest sample: no side ever waits) and `max_nodes` of
//! [`BridgeConfig`]. The runtime drains the goal service on the output lane after each frame and posts the
//! goals, in arrival order, into the latest-wins mailbox ([`crate::gaze::Mailbox`]): the newest is taken at the
//! next frame, the others are superseded. A goal's id is the sender's choice (non-zero; the state reports it).
use std::sync::Arc;

use iceoryx2::port::publisher::Publisher as IoxPublisher;
use iceoryx2::port::subscriber::Subscriber as IoxSubscriber;
use iceoryx2::prelude::*;

use super::services::{iox, node};
use super::{BridgeConfig, BridgeError, Ipc};
use crate::gaze::{Goal, GoalKind, Mailbox};
use abvs_runtime_core::gaze::{GazeState, GoalSource, Phase};
use abvs_runtime_core::messages::Published;
use abvs_runtime_core::stats::RunStats;

/// Goal publishers the goal service admits (processes that point the eyes).
pub const GOAL_PUBLISHERS: usize = 4;
/// Goals a runtime's subscriber holds between two frames (more are dropped, oldest first: latest wins).
pub const GOAL_BUFFER: usize = 8;
/// State subscribers the state service admits.
pub const STATE_SUBSCRIBERS: usize = 8;

/// [`GazeStateWire::flags`] bit: the frame was gated because its exposure overlapped a commanded saccade.
pub const FLAG_GATED_SACCADE: u32 = 1;
/// [`GazeStateWire::flags`] bit: the frame was gated (saccade or speed; its depth is NaN on purpose).
pub const FLAG_GATED: u32 = 2;

/// A gaze goal on `{prefix}/gaze/goal` (Python: `abvs_iceoryx2.GazeGoal`).
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("abvs::GazeGoal/1")]
pub struct GazeGoalWire {
    /// The goal's id, chosen by the sender (non-zero); the states report it.
    pub id: u64,
    /// 1 look_at, 2 pursue, 3 hold, 4 home ([`GoalKind`]); another value is refused as `non_finite`.
    pub kind: u32,
    /// Zero.
    pub reserved: u32,
    /// The point (m, left home camera frame): x right, y down, z forward.
    pub point_m: [f64; 3],
    /// The point's velocity (m/s, same frame): pursue only.
    pub velocity_m_s: [f64; 3],
}

/// The gaze at one frame on `{prefix}/gaze/state` (Python: `abvs_iceoryx2.GazeState`); see
/// [`abvs_runtime_core::gaze::GazeState`].
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("abvs::GazeState/1")]
pub struct GazeStateWire {
    /// The frame's pipeline sequence number (the depth sample's `seq`).
    pub seq: u64,
    /// The frame's instant (left mid-exposure, CLOCK_MONOTONIC ns).
    pub t_frame_ns: i64,
    /// The goal the state is about (0: none yet).
    pub goal_id: u64,
    /// 0 idle, 1 saccade, 2 pursuit, 3 settled, 4 refused ([`Phase`]).
    pub phase: u32,
    /// 0, or why the goal was refused: 1 + the index in [`abvs_runtime_core::gaze::Refusal::ALL`] (1 non_finite, 2
    /// behind_eyes, 3 too_near, 4 outside_workspace, 5 near_singular, 6 unreachable, 7 not_homed,
    /// 8 encoders_silent, 9 no_board, 10 send_failed).
    pub reason: u32,
    /// The commanded fixation point (m, left home camera frame); NaN when none.
    pub commanded_m: [f64; 3],
    /// The measured fixation point: closest approach of both optical axes from encoders and calibrated FK
    /// (m, left home camera frame); NaN when the axes do not converge in front.
    pub measured_m: [f64; 3],
    /// Distance from the midpoint of both optical centres to the measured fixation point (m); NaN as above.
    pub vergence_m: f64,
    /// The goal's planned saccade duration (ms; 0 without one).
    pub planned_ms: f64,
    /// [`FLAG_GATED_SACCADE`], [`FLAG_GATED`].
    pub flags: u32,
    /// Zero.
    pub reserved: u32,
}

impl GazeStateWire {
    /// The wire form of a frame's state.
    pub fn new(s: &GazeState, t_frame_ns: i64, gated: bool) -> GazeStateWire {
        GazeStateWire {
            seq: s.seq,
            t_frame_ns,
            goal_id: s.goal_id,
            phase: s.phase as u32,
            reason: s.reason.map_or(0, |r| r as u32),
            commanded_m: s.commanded_m,
            measured_m: s.measured_m,
            vergence_m: s.vergence_m,
            planned_ms: s.planned_ms,
            flags: (if s.gated_saccade { FLAG_GATED_SACCADE } else { 0 }) | (if gated { FLAG_GATED } else { 0 }),
            reserved: 0,
        }
    }

    /// The phase's name.
    pub fn phase_name(&self) -> &'static str {
        [Phase::Idle, Phase::Saccade, Phase::Pursuit, Phase::Settled, Phase::Refused]
            .into_iter()
            .find(|p| *p as u32 == self.phase)
            .map_or("unknown", Phase::name)
    }
}

impl GazeGoalWire {
    /// The goal it carries (an unknown kind becomes a look_at of a NaN point: refused as `non_finite`).
    pub fn goal(&self) -> Goal {
        match u8::try_from(self.kind).ok().and_then(GoalKind::from_u8) {
            Some(kind) => Goal { id: self.id, kind, point_m: self.point_m, velocity_m_s: self.velocity_m_s },
            None => Goal { id: self.id, kind: GoalKind::LookAt, point_m: [f64::NAN; 3], velocity_m_s: [0.0; 3] },
        }
    }
}

type GoalService = iceoryx2::service::port_factory::publish_subscribe::PortFactory<Ipc, GazeGoalWire, ()>;
type StateService = iceoryx2::service::port_factory::publish_subscribe::PortFactory<Ipc, GazeStateWire, ()>;

/// Opens (or creates) the goal service with its one set of settings (both sides).
pub fn goal_service(node: &Node<Ipc>, cfg: &BridgeConfig) -> Result<GoalService, BridgeError> {
    let name = cfg.service_name("gaze/goal");
    node.service_builder(&ServiceName::new(&name).map_err(iox(&name, "naming the service"))?)
        .publish_subscribe::<GazeGoalWire>()
        .max_publishers(GOAL_PUBLISHERS)
        .max_subscribers(cfg.max_subscribers)
        .subscriber_max_buffer_size(GOAL_BUFFER)
        .subscriber_max_borrowed_samples(1)
        .history_size(0)
        .enable_safe_overflow(true)
        .max_nodes(cfg.max_nodes)
        .open_or_create()
        .map_err(iox(&name, "opening the gaze goal service"))
}

/// Opens (or creates) the state service with its one set of settings (both sides).
pub fn state_service(node: &Node<Ipc>, cfg: &BridgeConfig) -> Result<StateService, BridgeError> {
    let name = cfg.service_name("gaze/state");
    node.service_builder(&ServiceName::new(&name).map_err(iox(&name, "naming the service"))?)
        .publish_subscribe::<GazeStateWire>()
        .max_publishers(1)
        .max_subscribers(STATE_SUBSCRIBERS)
        .subscriber_max_buffer_size(2)
        .subscriber_max_borrowed_samples(2)
        .history_size(1)
        .enable_safe_overflow(true)
        .max_nodes(cfg.max_nodes)
        .open_or_create()
        .map_err(iox(&name, "opening the gaze state service"))
}

/// The runtime's side: a sink on the output lane that publishes each frame's state and drains the goals
/// into the mailbox.
pub struct GazeBridge {
    goals: IoxSubscriber<Ipc, GazeGoalWire, ()>,
    states: IoxPublisher<Ipc, GazeStateWire, ()>,
    mailbox: Arc<Mailbox>,
    received: u64,
    published: u64,
    failures: u64,
    /// Its own CPU time on the output lane (ns) and the frames: the gaze service's cost there.
    cpu_ns: i64,
    frames: u64,
    _goal_service: GoalService,
    _state_service: StateService,
    _node: Node<Ipc>,
}

impl GazeBridge {
    /// Opens both services under `cfg`'s prefix; goals go to `mailbox`.
    pub fn new(cfg: &BridgeConfig, mailbox: Arc<Mailbox>) -> Result<GazeBridge, BridgeError> {
        let (node, _) = node(cfg, "gaze")?;
        let gs = goal_service(&node, cfg)?;
        let ss = state_service(&node, cfg)?;
        let gname = cfg.service_name("gaze/goal");
        let sname = cfg.service_name("gaze/state");
        let goals = gs.subscriber_builder().create().map_err(iox(&gname, "creating the goal subscriber"))?;
        let states = ss.publisher_builder().create().map_err(iox(&sname, "creating the state publisher"))?;
        Ok(GazeBridge {
            goals,
            states,
            mailbox,
            received: 0,
            published: 0,
            failures: 0,
            cpu_ns: 0,
            frames: 0,
            _goal_service: gs,
            _state_service: ss,
            _node: node,
        })
    }
}

impl abvs_runtime_core::sink::Sink for GazeBridge {
    fn name(&self) -> &'static str {
        "iceoryx2 gaze"
    }

    fn consume(&mut self, out: &Published) -> abvs_runtime_core::error::Result<()> {
        let t0 = abvs_runtime_core::cpu::thread_cpu_ns();
        self.exchange(out);
        self.cpu_ns += abvs_runtime_core::cpu::thread_cpu_ns() - t0;
        self.frames += 1;
        Ok(())
    }

    fn finish(&mut self, stats: &mut RunStats) {
        let us = self.cpu_ns as f64 * 1e-3 / self.frames.max(1) as f64;
        stats.extra.insert(
            "gaze_iceoryx2".into(),
            serde_json::json!({"goals_received": self.received, "states_published": self.published,
                "failures": self.failures, "cpu_us_per_frame": us}),
        );
    }
}

impl GazeBridge {
    /// Drains the goals into the mailbox and publishes the frame's state.
    fn exchange(&mut self, out: &Published) {
        while let Ok(Some(s)) = self.goals.receive() {
            self.received += 1;
            self.mailbox.post_from(s.payload().goal(), GoalSource::Iceoryx2);
        }
        let w = GazeStateWire::new(&out.motion.gaze, out.t_frame_ns, out.motion.gated);
        match self.states.loan_uninit().map(|s| s.write_payload(w)).map(|s| s.send()) {
            Ok(Ok(_)) => self.published += 1,
            _ => self.failures += 1,
        }
    }
}
