//! `abvs run --zenoh`: the ROS 2 messages of [`crate::ros2`] published over Zenoh on the keys
//! zenoh-bridge-ros2dds maps to ROS 2 topics (the topic without its leading slash: `abvs/depth`,
//! `abvs/camera_info`, `abvs/points`, `tf`, `abvs/joint_states`), CDR payloads as ROS 2 sends them.
//!
//! The session is opened with a standard Zenoh configuration (`--zenoh-config FILE`, JSON5; default: a
//! peer with Zenoh's defaults) plus the endpoints of `--zenoh-connect` (peers retry an endpoint that is
//! not up yet in the background, so the runtime starts without its consumers). Publishing runs on the
//! sink's own thread ([`Ros2OutSink`]): the network may block that thread (congestion control `Block`,
//! so a large cloud is never half-dropped), never the pipeline, whose frames wait in a bounded queue
//! that drops the oldest (counted in the stats under `zenoh`).
use std::path::Path;

use ::zenoh::pubsub::Publisher;
use ::zenoh::qos::CongestionControl;
use ::zenoh::{Config, Session, Wait};

use crate::error::RuntimeError;
use crate::ros2::{Topic, TOPICS};
use crate::sinks::ros2_out::{OutputError, Ros2OutSink, Ros2Writer};

/// Frames the publisher may fall behind by before the oldest is dropped: the newest matter on a network.
pub const DEFAULT_QUEUE: usize = 4;

/// The ROS 2 messages published over Zenoh, one publisher per key.
pub struct ZenohWriter {
    publishers: Vec<Publisher<'static>>,
    session: Session,
}

fn err(what: &str, e: impl std::fmt::Display) -> RuntimeError {
    RuntimeError::Invalid(format!("zenoh: {what}: {e}"))
}

/// The session's configuration: `config_file` (or Zenoh's defaults), then `connect` endpoints added.
pub fn config(config_file: Option<&Path>, connect: &[String]) -> crate::Result<Config> {
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
    /// Opens the session and declares the five publishers.
    pub fn open(config: Config) -> crate::Result<ZenohWriter> {
        let session = ::zenoh::open(config).wait().map_err(|e| err("opening the session", e))?;
        let mut publishers = Vec::with_capacity(TOPICS.len());
        for t in &TOPICS {
            let p = session
                .declare_publisher(t.key)
                .congestion_control(CongestionControl::Block)
                .wait()
                .map_err(|e| err(&format!("declaring the publisher of {}", t.key), e))?;
            publishers.push(p);
        }
        Ok(ZenohWriter { publishers, session })
    }
}

impl Ros2Writer for ZenohWriter {
    fn write(&mut self, topic: &'static Topic, _seq: u64, _stamp_ns: i64, cdr: &[u8]) -> Result<(), OutputError> {
        let i = TOPICS.iter().position(|t| t == topic).ok_or(OutputError::UnknownTopic(topic.topic))?;
        self.publishers[i].put(cdr).wait().map_err(|source| OutputError::Zenoh { key: topic.key, source })
    }

    fn finish(&mut self) -> Result<serde_json::Value, OutputError> {
        for p in self.publishers.drain(..) {
            let _ = p.undeclare().wait();
        }
        self.session.close().wait().map_err(|source| OutputError::Zenoh { key: "(closing the session)", source })?;
        Ok(serde_json::Value::Null)
    }
}

/// The Zenoh publisher as a pipeline sink (stats key `zenoh`).
pub fn sink(
    config_file: Option<&Path>,
    connect: &[String],
    queue: usize,
    blocking: bool,
) -> crate::Result<Ros2OutSink> {
    Ros2OutSink::new("zenoh", ZenohWriter::open(config(config_file, connect)?)?, queue, blocking)
}
