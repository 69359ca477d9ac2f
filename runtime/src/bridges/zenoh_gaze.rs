//! Gaze over Zenoh, as ROS 2 topics: the state of every frame out on `/abvs/gaze/state`, and (only with
//! `[bridges.zenoh] accept_gaze_goals = true`) goals in on `/abvs/gaze/goal`.
//!
//! | topic | type | direction |
//! | --- | --- | --- |
//! | `/abvs/gaze/goal` | geometry_msgs/msg/PointStamped, `frame_id` = `left_home_camera` (as in `/tf`), metres | in: a look_at |
//! | `/abvs/gaze/state` | std_msgs/msg/String: one JSON object per frame ([`state_json`]) | out |
//!
//! The state is a JSON string rather than a message of our own: a ROS 2 system decodes and echoes it without
//! building a package of ours (whose type hash every rmw_zenoh subscriber would have to match), the fields
//! are the iceoryx2 state's by the Python client's names, and fields can be added without breaking a
//! subscriber. Keys follow `[bridges.zenoh] keys` like the other topics (`abvs/gaze/goal`, or rmw_zenoh's typed
//! keys with liveliness tokens; a goal is taken whatever type hash its key carries: PointStamped is the same
//! message in every distro).
//!
//! Who may send goals ([`goal_access`], docs/gaze.md "Who may move the eyes"): the runtime refuses to take
//! goals over Zenoh unless the session's configuration authenticates its peers (user/password:
//! `transport.auth.usrpwd.dictionary_file`) or enables an access control that denies by default or by a rule
//! (`access_control`), or `insecure = true` says otherwise. Zenoh enforces both before a sample reaches this
//! module. A goal then goes into the latest-wins mailbox like any other (source `zenoh`): the rate limit and
//! the controller's refusals apply. The subscriber's callback runs on Zenoh's threads and only decodes and
//! posts (a flood replaces the goal waiting in the mailbox; nothing queues). A sample larger than
//! [`MAX_GOAL_BYTES`], one that does not decode, or one in another frame is dropped and counted.
use std::fmt::Write as _;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{SystemTime, UNIX_EPOCH};

use ::zenoh::liveliness::LivelinessToken;
use ::zenoh::pubsub::{Publisher, Subscriber};
use ::zenoh::qos::CongestionControl;
use ::zenoh::{Config, Session, Wait};
use serde::Deserialize;

use super::rmw_zenoh::{self, EntityKind, Qos};
use crate::gaze::{Goal, GoalKind, Mailbox};
use crate::ros2::{Topic, HEAD_FRAME};
use abvs_runtime_core::config::Ros2Keys;
use abvs_runtime_core::config::ZenohSettings;
use abvs_runtime_core::error::RuntimeError;
use abvs_runtime_core::gaze::{GazeState, GoalSource};
use abvs_runtime_core::messages::Published;
use abvs_runtime_core::stats::RunStats;

/// The goal topic and the state topic.
pub const TOPICS: [Topic; 2] = [
    Topic {
        topic: "/abvs/gaze/goal",
        key: "abvs/gaze/goal",
        type_name: "geometry_msgs/msg/PointStamped",
        schema: concat!(
            "std_msgs/Header header\ngeometry_msgs/Point point\n",
            "================================================================================\nMSG: std_msgs/Header\n",
            "builtin_interfaces/Time stamp\nstring frame_id\n",
            "================================================================================\nMSG: builtin_interfaces/Time\n",
            "int32 sec\nuint32 nanosec\n",
            "================================================================================\nMSG: geometry_msgs/Point\n",
            "float64 x\nfloat64 y\nfloat64 z\n",
        ),
        rihs01: "RIHS01_4c0296af86e01e562e9e0405d138a01537247580076c58ea38d7923ac1045897",
    },
    Topic {
        topic: "/abvs/gaze/state",
        key: "abvs/gaze/state",
        type_name: "std_msgs/msg/String",
        schema: "string data\n",
        rihs01: "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    },
];

/// Goal samples larger than this are dropped undecoded (a PointStamped with a 16-character frame id is 64).
pub const MAX_GOAL_BYTES: usize = 1024;

/// rmw_zenoh entity ids of the gaze topics: after the ROS 2 outputs' node (0) and publishers (1-8).
const FIRST_ENTITY_ID: u32 = 16;

fn err(what: &str, e: impl Into<Box<dyn std::error::Error + Send + Sync>>) -> RuntimeError {
    RuntimeError::Transport { what: format!("zenoh: {what}"), source: e.into() }
}

/// Where the runtime takes gaze goals from, for the start-up line; or the refusal to start, naming the
/// configuration key, when Zenoh goals are on without authentication or access control and not `insecure`.
pub fn goal_access(
    settings: &ZenohSettings,
    config: &Config,
    iceoryx: bool,
) -> abvs_runtime_core::error::Result<String> {
    let local = if iceoryx {
        "this machine (iceoryx2 `gaze/goal`, the Rust handle)"
    } else {
        "this process (the Rust handle; iceoryx2 off)"
    };
    if !settings.accept_gaze_goals {
        return Ok(format!("gaze goals from {local}; over Zenoh: off ([bridges.zenoh] accept_gaze_goals)"));
    }
    let get = |k: &str| config.get_json(k).unwrap_or_else(|_| "null".into());
    let users = get("transport/auth/usrpwd/dictionary_file") != "null";
    let acl_on = get("access_control/enabled") == "true";
    let deny_default = get("access_control/default_permission") == "\"deny\"";
    let deny_rule = serde_json::from_str::<serde_json::Value>(&get("access_control/rules"))
        .ok()
        .and_then(|r| r.as_array().map(|r| r.iter().any(|r| r["permission"] == "deny")))
        .unwrap_or(false);
    let acl = acl_on && (deny_default || deny_rule);
    let file = settings.config.as_ref().map_or("Zenoh's defaults".to_string(), |p| p.display().to_string());
    let mut how = Vec::new();
    if users {
        how.push("authenticated peers (user/password)".to_string());
    }
    if acl {
        let d = if deny_default { "deny by default" } else { "deny rules" };
        how.push(format!("access control ({d})"));
    }
    if how.is_empty() {
        if !settings.insecure {
            return Err(RuntimeError::Invalid(format!(
                "bridges.zenoh.accept_gaze_goals: the Zenoh configuration ({file}) neither authenticates peers \
                 (transport.auth.usrpwd.dictionary_file) nor enables an access control that denies \
                 (access_control.enabled with default_permission \"deny\" or a deny rule): anyone on the network \
                 could move the eyes. Set bridges.zenoh.config (docs/gaze.md, config/zenoh-gaze-acl.json5), or \
                 bridges.zenoh.insecure = true (--zenoh-insecure) to accept that"
            )));
        }
        how.push("INSECURE: anyone who reaches the Zenoh session (no authentication, no access control)".into());
    }
    Ok(format!("gaze goals from {local}; over Zenoh `/abvs/gaze/goal` ({file}): {}", how.join(", ")))
}

/// A PointStamped as CDR carries it.
#[derive(Deserialize)]
struct PointStamped {
    _sec: i32,
    _nanosec: u32,
    frame_id: String,
    x: f64,
    y: f64,
    z: f64,
}

/// The look_at goal of a `/abvs/gaze/goal` sample (id 0: the caller assigns it), or why it is dropped.
pub fn decode_goal(bytes: &[u8]) -> Result<Goal, &'static str> {
    if bytes.len() > MAX_GOAL_BYTES {
        return Err("oversized");
    }
    let p: PointStamped = cdr::deserialize(bytes).map_err(|_| "undecodable")?;
    if p.frame_id != HEAD_FRAME {
        return Err("wrong_frame");
    }
    Ok(Goal { id: 0, kind: GoalKind::LookAt, point_m: [p.x, p.y, p.z], velocity_m_s: [0.0; 3] })
}

/// Counters shared with the subscriber's callback.
#[derive(Debug, Default)]
struct GoalCounts {
    received: AtomicU64,
    posted: AtomicU64,
    oversized: AtomicU64,
    undecodable: AtomicU64,
    wrong_frame: AtomicU64,
}

/// `v` as JSON: a number, or null when not finite.
fn num(out: &mut String, v: f64) {
    if v.is_finite() {
        let _ = write!(out, "{v}");
    } else {
        out.push_str("null");
    }
}

fn point(out: &mut String, p: &[f64; 3]) {
    if p.iter().all(|v| v.is_finite()) {
        let _ = write!(out, "[{},{},{}]", p[0], p[1], p[2]);
    } else {
        out.push_str("null");
    }
}

/// The state's JSON (written into `out`): `seq`, `stamp_ns` (the frame's, CLOCK_MONOTONIC), `goal_id`,
/// `source` (rust, iceoryx2, zenoh, or null), `phase`, `reason` (a refusal's name or null),
/// `commanded_fixation`, `measured_fixation` ([x, y, z] m, left home camera frame, or null), `vergence_m`,
/// `planned_ms`, `gated_saccade`, `gated`, `goal_waiting` (a newer goal waits for the rate limit).
pub fn state_json(out: &mut String, s: &GazeState, stamp_ns: i64, gated: bool) {
    out.clear();
    let _ = write!(out, "{{\"seq\":{},\"stamp_ns\":{stamp_ns},\"goal_id\":{},\"source\":", s.seq, s.goal_id);
    match s.source {
        Some(src) => {
            let _ = write!(out, "\"{}\"", src.name());
        }
        None => out.push_str("null"),
    }
    let _ = write!(out, ",\"phase\":\"{}\",\"reason\":", s.phase.name());
    match s.reason {
        Some(r) => {
            let _ = write!(out, "\"{}\"", r.name());
        }
        None => out.push_str("null"),
    }
    out.push_str(",\"commanded_fixation\":");
    point(out, &s.commanded_m);
    out.push_str(",\"measured_fixation\":");
    point(out, &s.measured_m);
    out.push_str(",\"vergence_m\":");
    num(out, s.vergence_m);
    out.push_str(",\"planned_ms\":");
    num(out, s.planned_ms);
    let _ =
        write!(out, ",\"gated_saccade\":{},\"gated\":{gated},\"goal_waiting\":{}}}", s.gated_saccade, s.goal_waiting);
}

/// A std_msgs/msg/String's CDR (little-endian encapsulation) of `text`, written into `out`.
pub fn string_cdr(out: &mut Vec<u8>, text: &str) {
    out.clear();
    out.extend_from_slice(&[0, 1, 0, 0]);
    out.extend_from_slice(&(text.len() as u32 + 1).to_le_bytes());
    out.extend_from_slice(text.as_bytes());
    out.push(0);
}

/// The sink on the output lane: publishes each frame's state; holds the goal subscriber (when on).
pub struct ZenohGaze {
    states: Publisher<'static>,
    /// rmw_zenoh: the state publisher's GID and next sequence number.
    rmw: Option<([u8; 16], i64)>,
    goals: Option<Subscriber<()>>,
    counts: Arc<GoalCounts>,
    tokens: Vec<LivelinessToken>,
    json: String,
    cdr: Vec<u8>,
    published: u64,
    failures: u64,
    _session: Session,
}

impl ZenohGaze {
    /// The gaze topics on `session` with the key layout of `settings`; goals (when `accept_gaze_goals`) go
    /// to `mailbox`. `node_declared`: the ROS 2 outputs already declared the rmw_zenoh node's token.
    pub fn new(
        session: Session,
        settings: &ZenohSettings,
        mailbox: Arc<Mailbox>,
        node_declared: bool,
    ) -> abvs_runtime_core::error::Result<ZenohGaze> {
        let mut node =
            rmw_zenoh::Node::new(settings.domain, session.zid().to_string(), &settings.namespace, &settings.node);
        node.skip_to(FIRST_ENTITY_ID);
        let mut tokens = Vec::new();
        let rmw = settings.keys == Ros2Keys::RmwZenoh;
        if rmw && !node_declared {
            let t = session.liveliness().declare_token(node.token()).wait();
            tokens.push(t.map_err(|e| err(&format!("declaring the node's token {}", node.token()), e))?);
        }
        let [goal_topic, state_topic] = &TOPICS;
        let (state_key, state_rmw) = if rmw {
            let (e, t) = node
                .declare(&session, EntityKind::Publisher, state_topic, settings.distro, Qos::SENSOR_DATA)
                .map_err(|e| err("declaring the gaze state's token", e))?;
            tokens.push(t);
            (e.key, Some((e.gid, 1)))
        } else {
            (state_topic.key.to_string(), None)
        };
        // the state never blocks the output lane: a congested link drops it
        let states = session
            .declare_publisher(state_key.clone())
            .congestion_control(CongestionControl::Drop)
            .wait()
            .map_err(|e| err(&format!("declaring the publisher of {state_key}"), e))?;
        let counts = Arc::new(GoalCounts::default());
        let goals = if settings.accept_gaze_goals {
            let key = if rmw {
                let q = Qos { reliable: true, transient_local: false, depth: 1 };
                let (e, t) = node
                    .declare(&session, EntityKind::Subscription, goal_topic, settings.distro, q)
                    .map_err(|e| err("declaring the gaze goal's token", e))?;
                tokens.push(t);
                // any type hash: a Humble publisher's (TypeHashNotSupported) as well as Jazzy's
                let (head, _) = e.key.rsplit_once('/').expect("a typed key ends with its hash");
                format!("{head}/*")
            } else {
                goal_topic.key.to_string()
            };
            let (c, mb) = (counts.clone(), mailbox);
            let sub = session
                .declare_subscriber(key.clone())
                .callback(move |sample| {
                    c.received.fetch_add(1, Ordering::Relaxed);
                    let bytes = sample.payload().to_bytes();
                    match decode_goal(&bytes) {
                        Ok(mut g) => {
                            g.id = mb.next_id();
                            mb.post_from(g, GoalSource::Zenoh);
                            c.posted.fetch_add(1, Ordering::Relaxed);
                        }
                        Err("oversized") => {
                            c.oversized.fetch_add(1, Ordering::Relaxed);
                        }
                        Err("wrong_frame") => {
                            c.wrong_frame.fetch_add(1, Ordering::Relaxed);
                        }
                        Err(_) => {
                            c.undecodable.fetch_add(1, Ordering::Relaxed);
                        }
                    }
                })
                .wait()
                .map_err(|e| err(&format!("declaring the subscriber of {key}"), e))?;
            Some(sub)
        } else {
            None
        };
        Ok(ZenohGaze {
            states,
            rmw: state_rmw,
            goals,
            counts,
            tokens,
            json: String::with_capacity(512),
            cdr: Vec::with_capacity(528),
            published: 0,
            failures: 0,
            _session: session,
        })
    }
}

impl abvs_runtime_core::sink::Sink for ZenohGaze {
    fn name(&self) -> &'static str {
        "zenoh gaze"
    }

    fn consume(&mut self, out: &Published) -> abvs_runtime_core::error::Result<()> {
        state_json(&mut self.json, &out.motion.gaze, out.t_frame_ns, out.motion.gated);
        string_cdr(&mut self.cdr, &self.json);
        let put = self.states.put(&self.cdr[..]);
        let r = match &mut self.rmw {
            None => put.wait(),
            Some((gid, seq)) => {
                let now = SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_nanos() as i64);
                let a = rmw_zenoh::attachment(*seq, now, gid);
                *seq += 1;
                put.attachment(a.to_vec()).wait()
            }
        };
        match r {
            Ok(()) => self.published += 1,
            Err(_) => self.failures += 1,
        }
        Ok(())
    }

    fn finish(&mut self, stats: &mut RunStats) {
        let accept_goals = self.goals.is_some();
        if let Some(s) = self.goals.take() {
            let _ = s.undeclare().wait();
        }
        for t in self.tokens.drain(..) {
            let _ = t.undeclare().wait();
        }
        let c = &self.counts;
        let n = |a: &AtomicU64| a.load(Ordering::Relaxed);
        stats.extra.insert(
            "gaze_zenoh".into(),
            serde_json::json!({
                "accept_goals": accept_goals,
                "goals_received": n(&c.received),
                "goals_posted": n(&c.posted),
                "dropped": {"oversized": n(&c.oversized), "undecodable": n(&c.undecodable), "wrong_frame": n(&c.wrong_frame)},
                "states_published": self.published,
                "failures": self.failures,
            }),
        );
    }
}

/// The session of `[bridges.zenoh]`: its configuration file (a relative user/password dictionary is
/// relative to that file), plus `connect` and `listen` endpoints.
pub fn config(settings: &ZenohSettings) -> abvs_runtime_core::error::Result<Config> {
    let mut c = super::zenoh::config(settings.config.as_deref(), &settings.connect)?;
    if !settings.shared_memory {
        // no shared memory at all: neither the writer's pool nor Zenoh's own for large payloads
        const SHM: &str = "transport/shared_memory/enabled";
        c.insert_json5(SHM, "false").map_err(|e| err(SHM, e))?;
    }
    const DICT: &str = "transport/auth/usrpwd/dictionary_file";
    let dict = c.get_json(DICT).ok().and_then(|j| serde_json::from_str::<Option<String>>(&j).ok().flatten());
    if let (Some(d), Some(dir)) = (dict, settings.config.as_deref().and_then(|p| p.parent())) {
        if std::path::Path::new(&d).is_relative() {
            let abs = serde_json::to_string(&dir.join(&d)).map_err(|e| err(DICT, e))?;
            c.insert_json5(DICT, &abs).map_err(|e| err(DICT, e))?;
        }
    }
    if !settings.listen.is_empty() {
        let json = serde_json::to_string(&settings.listen).map_err(|e| err("listen endpoints", e))?;
        c.insert_json5("listen/endpoints", &json).map_err(|e| err(&format!("listen endpoints {json}"), e))?;
    }
    Ok(c)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A PointStamped as rclpy writes it: header (stamp, frame_id), then the point (8-byte aligned).
    pub fn point_stamped(frame: &str, p: [f64; 3]) -> Vec<u8> {
        let mut b = vec![0u8, 1, 0, 0];
        b.extend_from_slice(&5i32.to_le_bytes());
        b.extend_from_slice(&7u32.to_le_bytes());
        b.extend_from_slice(&(frame.len() as u32 + 1).to_le_bytes());
        b.extend_from_slice(frame.as_bytes());
        b.push(0);
        while (b.len() - 4) % 8 != 0 {
            b.push(0);
        }
        for v in p {
            b.extend_from_slice(&v.to_le_bytes());
        }
        b
    }

    #[test]
    fn goals_decode_and_states_encode() {
        let b = point_stamped(HEAD_FRAME, [0.1, -0.05, 0.8]);
        let g = decode_goal(&b).unwrap();
        assert_eq!((g.kind, g.point_m), (GoalKind::LookAt, [0.1, -0.05, 0.8]));
        assert_eq!(decode_goal(&point_stamped("left_rect_camera", [0.0; 3])).unwrap_err(), "wrong_frame");
        assert_eq!(decode_goal(&b[..20]).unwrap_err(), "undecodable");
        assert_eq!(decode_goal(&vec![0u8; MAX_GOAL_BYTES + 1]).unwrap_err(), "oversized");
        let mut j = String::new();
        let s = GazeState { goal_id: 3, source: Some(GoalSource::Zenoh), ..GazeState::default() };
        state_json(&mut j, &s, 42, true);
        let v: serde_json::Value = serde_json::from_str(&j).unwrap();
        assert_eq!(v["source"], "zenoh");
        assert_eq!(v["phase"], "idle");
        assert!(v["measured_fixation"].is_null() && v["gated"] == true && v["stamp_ns"] == 42);
        let mut c = Vec::new();
        string_cdr(&mut c, "ab");
        assert_eq!(c, [0, 1, 0, 0, 3, 0, 0, 0, b'a', b'b', 0]);
    }
}
