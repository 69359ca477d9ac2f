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
//! Large messages (depth images, clouds: [`SHM_MIN_BYTES`] and more) are written, with `shared_memory`
//! (the default), straight into a buffer of the writer's Zenoh shared-memory pool and put as such: a
//! subscriber on this computer whose session enables shared memory receives a descriptor of the buffer,
//! not the bytes (no copy into Zenoh's batches nor the socket); any other subscriber gets the same bytes,
//! which Zenoh copies out of the buffer. When the pool has no free buffer (subscribers still hold them) the
//! message goes the ordinary way (counted: `shm_fallbacks`), so the pool never blocks the sink. Without
//! shared memory, a large message goes out without a copy of ours: the sample's payload is the message's
//! encoded fields and the snapshot's array itself ([`crate::ros2::Cdr`]), which Zenoh copies once into its
//! batches. A topic that no subscriber matches (Zenoh's matching status) is neither copied nor encoded
//! ([`Ros2Writer::unwanted`]).
use std::path::Path;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::Arc;
use std::time::{SystemTime, UNIX_EPOCH};

use ::zenoh::bytes::ZBytes;
use ::zenoh::liveliness::LivelinessToken;
use ::zenoh::pubsub::Publisher;
use ::zenoh::qos::CongestionControl;
use ::zenoh::shm::{GarbageCollect, PosixShmProviderBackend, ShmProvider, ShmProviderBuilder};
use ::zenoh::{Config, Session, Wait};

use super::rmw_zenoh::{self, EntityKind, Qos};
use crate::ros2::{Cdr, Topic, TopicSet, TOPICS};
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

/// Messages this large and larger go through shared memory: the depth images and the clouds; a smaller
/// one (CameraInfo, /tf, JointState: < 1 KiB; a cloud of few points) fits one of Zenoh's 64 KiB batches
/// and costs less copied than a buffer's bookkeeping.
pub const SHM_MIN_BYTES: usize = 64 * 1024;

/// The writer's shared-memory pool, made at the first large message: [`SHM_POOL_MESSAGES`] times its size
/// (at least 32 MiB), so that a few frames' large messages fit while subscribers still hold earlier ones.
struct Shm {
    provider: Option<ShmProvider<PosixShmProviderBackend>>,
    /// Why the pool could not be made (then every message goes the ordinary way).
    failed: Option<String>,
    pool_bytes: usize,
    messages: u64,
    fallbacks: u64,
}

/// The pool holds this many of the first large message (the main depth image: a frame's large messages
/// are at most about four of it, the cloud's 16 bytes a point against the image's 4 a pixel, plus the fovea's
/// and the confidence: 32 hold about five frames, for a subscriber that copies each sample out before it lets
/// go; 16 fell back to the ordinary path for 3 % of the messages with such a Python subscriber).
const SHM_POOL_MESSAGES: usize = 32;

impl Shm {
    /// `msg` in a buffer of the pool, or `None` (no pool, or no free buffer: the caller sends it the
    /// ordinary way).
    fn payload(&mut self, msg: &Cdr<'_>) -> Option<ZBytes> {
        let len = msg.len();
        if self.provider.is_none() && self.failed.is_none() {
            let size = (SHM_POOL_MESSAGES * len).max(32 << 20);
            match ShmProviderBuilder::default_backend(size).wait() {
                Ok(p) => (self.provider, self.pool_bytes) = (Some(p), size),
                Err(e) => self.failed = Some(e.to_string()),
            }
        }
        let provider = self.provider.as_ref()?;
        // GarbageCollect: when the pool is full, reclaim the buffers subscribers let go and try once more;
        // never waits
        let Ok(mut buf) = provider.alloc(len).with_policy::<GarbageCollect>().wait() else {
            self.fallbacks += 1;
            return None;
        };
        let (h, b) = (msg.head.len(), msg.body.map_or(&[][..], |b| b.as_ref()));
        buf[..h].copy_from_slice(msg.head);
        buf[h..h + b.len()].copy_from_slice(b);
        buf[h + b.len()..].copy_from_slice(msg.tail);
        self.messages += 1;
        Some(ZBytes::from(buf))
    }
}

/// The ROS 2 messages published over Zenoh, one publisher per key.
pub struct ZenohWriter {
    outputs: Vec<Output>,
    /// rmw_zenoh: the node's and the publishers' liveliness tokens (dropping one undeclares it).
    tokens: Vec<LivelinessToken>,
    /// Bit i set while no subscriber matches output i (the matching listeners keep it current).
    unwanted: Arc<AtomicU32>,
    /// With `shared_memory`: the pool the large messages are written into.
    shm: Option<Shm>,
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
        let shm = settings.shared_memory.then_some(Shm {
            provider: None,
            failed: None,
            pool_bytes: 0,
            messages: 0,
            fallbacks: 0,
        });
        Ok(ZenohWriter { outputs, tokens, unwanted, shm, session })
    }
}

/// A sample's payload: a small message copied whole; a large one as its fields and the shared array
/// (Zenoh's slices: the array is not copied here, only into Zenoh's batches).
fn payload(msg: Cdr<'_>) -> ZBytes {
    let Some(body) = msg.body else { return ZBytes::from(msg.head) };
    let mut w = ZBytes::writer();
    std::io::Write::write_all(&mut w, msg.head).unwrap_or(());
    w.append(ZBytes::from(bytes::Bytes::from_owner(body.clone())));
    std::io::Write::write_all(&mut w, msg.tail).unwrap_or(());
    w.finish()
}

impl Ros2Writer for ZenohWriter {
    fn write(&mut self, topic: &'static Topic, _seq: u64, _stamp_ns: i64, msg: Cdr<'_>) -> Result<(), OutputError> {
        let out = self.outputs.iter_mut().find(|o| o.topic == topic).ok_or(OutputError::UnknownTopic(topic.topic))?;
        let shm = self.shm.as_mut().filter(|_| msg.len() >= SHM_MIN_BYTES).and_then(|s| s.payload(&msg));
        let put = out.publisher.put(shm.unwrap_or_else(|| payload(msg)));
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
            Some(s) => serde_json::json!({
                "shared_memory": true,
                "shm_messages": s.messages,
                "shm_fallbacks": s.fallbacks,
                "shm_pool_bytes": s.pool_bytes,
                "shm_error": s.failed,
            }),
        })
    }
}
