//! `abvs run --zenoh`: the ROS 2 messages of [`crate::ros2`] published over Zenoh, CDR payloads as ROS 2
//! sends them, under one of two key layouts (`--ros2-keys`, [`Ros2Keys`]):
//! - `bridge` (the default): the keys zenoh-bridge-ros2dds maps to ROS 2 topics (the topic without its
//!   leading slash: `abvs/depth`, `abvs/camera_info`, `abvs/points`, `tf`, `abvs/joint_states`, and with
//!   the fovea `abvs/fovea/depth`, `abvs/fovea/camera_info`, `abvs/fovea/points`);
//! - `rmw-zenoh`: rmw_zenoh's wire format ([`super::rmw_zenoh`]): typed keys with the `--ros-distro`'s type
//!   hashes, the runtime declared as a ROS 2 node with a liveliness token per publisher, and the 33-byte
//!   attachment (sequence number, source time, publisher GID) on every sample.
//!
//! The session is opened with a standard Zenoh configuration (`--zenoh-config FILE`, JSON5; default: a
//! peer with Zenoh's defaults) plus the endpoints of `--zenoh-connect` and `--zenoh-listen` (peers retry an
//! endpoint that is not up yet in the background, so the runtime starts without its consumers); the gaze
//! topics share it (`super::zenoh_gaze`, which also says who may send goals). Publishing runs on the
//! sink's own thread ([`crate::sinks::ros2_out::Ros2OutSink`]): the network may block that thread (congestion control `Block`,
//! so a large cloud is never half-dropped), never the pipeline, whose frames wait in a bounded queue
//! that drops the oldest (counted in the stats under `zenoh`).
//!
//! Large messages (depth images, clouds: [`SHM_MIN_BYTES`] and more) are built, with `shared_memory`
//! (the default), in buffers of the writer's Zenoh shared-memory pool ([`super::zenoh_shm`]: the output
//! thread's one copy of the array goes there) and put as such. Without shared memory (or when the pool is
//! full), a large message goes out without a copy of ours: the sample's payload is the snapshot's buffer
//! of the message itself, which Zenoh copies once into its batches. A topic that no subscriber matches
//! (Zenoh's matching status) is neither copied nor encoded ([`Ros2Writer::unwanted`]).
use std::path::Path;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::Arc;
use std::time::{SystemTime, UNIX_EPOCH};

use ::zenoh::bytes::ZBytes;
use ::zenoh::liveliness::LivelinessToken;
use ::zenoh::pubsub::Publisher;
use ::zenoh::qos::CongestionControl;
use ::zenoh::{Config, Session, Wait};

use super::rmw_zenoh::{self, EntityKind, Qos};
pub use super::zenoh_shm::SHM_MIN_BYTES;
use super::zenoh_shm::{self, ShmPool};
use crate::ros2::{BufferPool, Payload, Topic, TopicSet, TOPICS};
use crate::sinks::ros2_out::{OutputError, Ros2Writer};
use abvs_runtime_core::config::Ros2Keys;
use abvs_runtime_core::config::ZenohSettings;
use abvs_runtime_core::error::RuntimeError;

/// One publisher per topic, and in the rmw_zenoh format what its samples carry.
struct Output {
    topic: &'static Topic,
    publisher: Publisher<'static>,
    /// rmw_zenoh: the publisher's GID and its next sequence number (from 1).
    rmw: Option<([u8; 16], i64)>,
}

/// The ROS 2 messages published over Zenoh, one publisher per key.
pub struct ZenohWriter {
    outputs: Vec<Output>,
    /// rmw_zenoh: the node's and the publishers' liveliness tokens (dropping one undeclares it).
    tokens: Vec<LivelinessToken>,
    /// Bit i set while no subscriber matches output i (the matching listeners keep it current).
    unwanted: Arc<AtomicU32>,
    /// With `shared_memory`: the pool the large messages are written into, and how many were sent so.
    shm: Option<(Arc<ShmPool>, u64)>,
    session: Session,
}

fn err(what: &str, e: impl Into<Box<dyn std::error::Error + Send + Sync>>) -> RuntimeError {
    RuntimeError::Transport { what: format!("zenoh: {what}"), source: e.into() }
}

/// The session's configuration: `config_file` (or Zenoh's defaults), then `connect` endpoints added.
pub fn config(config_file: Option<&Path>, connect: &[String]) -> abvs_runtime_core::error::Result<Config> {
    let mut c = match config_file {
        Some(p) => Config::from_file(p).map_err(|e| err(&format!("configuration {}", p.display()), e))?,
        None => Config::default(),
    };
    if !connect.is_empty() {
        let json = serde_json::to_string(connect).map_err(|e| err("connect endpoints", e))?;
        c.insert_json5("connect/endpoints", &json).map_err(|e| err(&format!("connect endpoints {json}"), e))?;
    }
    Ok(c)
}

impl ZenohWriter {
    /// Opens the session and declares a publisher per topic of `set` (the main five, the fovea's three, the
    /// confidence) with the key layout of `settings` (in the rmw_zenoh format also the node's and the
    /// publishers' liveliness tokens).
    pub fn open(
        config: Config,
        settings: &ZenohSettings,
        set: TopicSet,
    ) -> abvs_runtime_core::error::Result<ZenohWriter> {
        let session = ::zenoh::open(config).wait().map_err(|e| err("opening the session", e))?;
        Self::on_session(session, settings, set)
    }

    /// The same on an open session (shared with the gaze topics, `bridges::zenoh_gaze`).
    pub fn on_session(
        session: Session,
        settings: &ZenohSettings,
        set: TopicSet,
    ) -> abvs_runtime_core::error::Result<ZenohWriter> {
        let mut node =
            rmw_zenoh::Node::new(settings.domain, session.zid().to_string(), &settings.namespace, &settings.node);
        let mut tokens = Vec::new();
        if settings.keys == Ros2Keys::RmwZenoh {
            let t = session.liveliness().declare_token(node.token()).wait();
            tokens.push(t.map_err(|e| err(&format!("declaring the node's token {}", node.token()), e))?);
        }
        let topics = set.topics();
        let mut outputs = Vec::with_capacity(topics.len());
        // nobody until the matching listeners say otherwise
        let unwanted = Arc::new(AtomicU32::new(u32::MAX));
        for &t in &topics {
            // the topic's bit in the snapshot's skip mask: its place in TOPICS (not in this run's list, which
            // leaves the fovea's out when the run has none)
            let i = TOPICS.iter().position(|x| x == t).unwrap_or(0);
            let (key, rmw) = match settings.keys {
                Ros2Keys::Bridge => (t.key.to_string(), None),
                Ros2Keys::RmwZenoh => {
                    let (e, token) = node
                        .declare(&session, EntityKind::Publisher, t, settings.distro, Qos::SENSOR_DATA)
                        .map_err(|e| err(&format!("declaring the liveliness token of {}", t.topic), e))?;
                    tokens.push(token);
                    (e.key, Some((e.gid, 1)))
                }
            };
            let publisher = session
                .declare_publisher(key.clone())
                .congestion_control(CongestionControl::Block)
                .wait()
                .map_err(|e| err(&format!("declaring the publisher of {key}"), e))?;
            let set = {
                let unwanted = Arc::clone(&unwanted);
                move |matching: bool| match matching {
                    true => unwanted.fetch_and(!(1 << i), Ordering::Relaxed),
                    false => unwanted.fetch_or(1 << i, Ordering::Relaxed),
                }
            };
            let on_change = set.clone();
            publisher
                .matching_listener()
                .callback(move |s| {
                    on_change(s.matching());
                })
                .background()
                .wait()
                .map_err(|e| err(&format!("declaring the matching listener of {key}"), e))?;
            // the subscribers already there (the listener reports changes)
            let now = publisher.matching_status().wait().map_err(|e| err(&format!("matching status of {key}"), e))?;
            set(now.matching());
            outputs.push(Output { topic: t, publisher, rmw });
        }
        let shm = settings.shared_memory.then(|| (Arc::default(), 0));
        Ok(ZenohWriter { outputs, tokens, unwanted, shm, session })
    }
}

impl Ros2Writer for ZenohWriter {
    fn write(&mut self, topic: &'static Topic, _seq: u64, _stamp_ns: i64, msg: Payload<'_>) -> Result<(), OutputError> {
        let out = self.outputs.iter_mut().find(|o| o.topic == topic).ok_or(OutputError::UnknownTopic(topic.topic))?;
        let payload = match msg {
            Payload::Small(b) => ZBytes::from(b),
            // the snapshot's buffer, shared: Zenoh copies it into its batches
            Payload::Shared(m) => ZBytes::from(bytes::Bytes::from_owner(m)),
            Payload::Lent(b, len) => {
                let b = zenoh_shm::payload(b, len).ok_or(OutputError::ForeignBuffer(topic.topic))?;
                if let Some((_, n)) = &mut self.shm {
                    *n += 1;
                }
                b
            }
        };
        let put = out.publisher.put(payload);
        let r = match &mut out.rmw {
            None => put.wait(),
            Some((gid, seq)) => {
                // rmw_zenoh's source timestamp: the wall clock when the sample is sent
                let now = SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_nanos() as i64);
                let a = rmw_zenoh::attachment(*seq, now, gid);
                *seq += 1;
                put.attachment(a.to_vec()).wait()
            }
        };
        r.map_err(|source| OutputError::Zenoh { key: topic.key, source })
    }

    fn unwanted(&self) -> Option<Arc<AtomicU32>> {
        Some(Arc::clone(&self.unwanted))
    }

    fn pool(&self) -> Option<Arc<dyn BufferPool>> {
        self.shm.as_ref().map(|(p, _)| Arc::clone(p) as Arc<dyn BufferPool>)
    }

    fn skipped(&mut self, topic: &'static Topic) {
        // rmw_zenoh numbers every publication, received or not (as rmw_publish does)
        if let Some(Some((_, seq))) = self.outputs.iter_mut().find(|o| o.topic == topic).map(|o| &mut o.rmw) {
            *seq += 1;
        }
    }

    fn finish(&mut self) -> Result<serde_json::Value, OutputError> {
        for t in self.tokens.drain(..) {
            let _ = t.undeclare().wait();
        }
        for o in self.outputs.drain(..) {
            let _ = o.publisher.undeclare().wait();
        }
        self.session.close().wait().map_err(|source| OutputError::Zenoh { key: "(closing the session)", source })?;
        Ok(match &self.shm {
            None => serde_json::json!({ "shared_memory": false }),
            Some((pool, messages)) => pool.report(*messages),
        })
    }
}
