//! `abvs run --mcap FILE`: the ROS 2 messages of [`crate::ros2`] recorded as MCAP (profile `ros2`, schemas
//! `ros2msg` named as in ROS 2, messages `cdr`), which Foxglove and `ros2 bag` read. Written on the sink's
//! own thread ([`Ros2OutSink`]); log and publish times are the frame's stamp (CLOCK_MONOTONIC ns).
use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use crate::ros2::{Payload, Topic, TopicSet};
use crate::sinks::ros2_out::{OutputError, Ros2OutSink, Ros2Writer};
use abvs_runtime_core::error::RuntimeError;

/// The ROS 2 messages written to an MCAP file (profile ros2), one channel per topic.
pub struct McapWriter {
    writer: Option<mcap::Writer<BufWriter<File>>>,
    topics: Vec<&'static Topic>,
    channels: Vec<u16>,
    counts: Vec<u64>,
    path: String,
}

impl McapWriter {
    /// Creates `path` (replacing a file there) with a channel and its schema per topic of `set`: the main
    /// five, the fovea's three, the confidence.
    pub fn create(path: &Path, set: TopicSet) -> abvs_runtime_core::error::Result<McapWriter> {
        let name = path.display().to_string();
        let err = |what: &str, e: mcap::McapError| RuntimeError::Transport {
            what: format!("--mcap {name}: {what}"),
            source: Box::new(e),
        };
        let file = File::create(path)
            .map_err(|e| RuntimeError::Transport { what: format!("--mcap {name}"), source: Box::new(e) })?;
        let mut writer = mcap::WriteOptions::new()
            .profile("ros2")
            .library(concat!("abvs ", env!("CARGO_PKG_VERSION")))
            // no compression: the recorder must keep up on the robot's cores; depth and clouds compress poorly
            .compression(None)
            .create(BufWriter::with_capacity(1 << 20, file))
            .map_err(|e| err("starting the file", e))?;
        let topics = set.topics();
        let mut channels = Vec::with_capacity(topics.len());
        let mut schemas = BTreeMap::new();
        for &t in &topics {
            // one schema a type (the fovea's topics have the main map's)
            let schema = match schemas.get(t.type_name) {
                Some(&s) => s,
                None => {
                    let s =
                        writer.add_schema(t.type_name, "ros2msg", t.schema.as_bytes()).map_err(|e| err("schema", e))?;
                    *schemas.entry(t.type_name).or_insert(s)
                }
            };
            channels.push(writer.add_channel(schema, t.topic, "cdr", &BTreeMap::new()).map_err(|e| err("channel", e))?);
        }
        let counts = vec![0; topics.len()];
        Ok(McapWriter { writer: Some(writer), topics, channels, counts, path: name })
    }
}

impl Ros2Writer for McapWriter {
    fn write(&mut self, topic: &'static Topic, seq: u64, stamp_ns: i64, msg: Payload<'_>) -> Result<(), OutputError> {
        let i = self.topics.iter().position(|&t| t == topic).ok_or(OutputError::UnknownTopic(topic.topic))?;
        let w = self.writer.as_mut().ok_or(OutputError::Closed)?;
        let t = stamp_ns.max(0) as u64;
        let header = mcap::records::MessageHeader {
            channel_id: self.channels[i],
            sequence: seq as u32,
            log_time: t,
            publish_time: t,
        };
        w.write_to_known_channel(&header, msg.bytes())
            .map_err(|source| OutputError::Mcap { path: self.path.clone(), source })?;
        self.counts[i] += 1;
        Ok(())
    }

    fn finish(&mut self) -> Result<serde_json::Value, OutputError> {
        if let Some(mut w) = self.writer.take() {
            w.finish().map_err(|source| OutputError::Mcap { path: self.path.clone(), source })?;
            // the BufWriter flushes as it drops; flush explicitly to see the error
            use std::io::Write;
            w.into_inner().flush().map_err(|source| OutputError::Io { path: self.path.clone(), source })?;
        }
        let per: serde_json::Map<_, _> =
            self.topics.iter().zip(&self.counts).map(|(t, n)| (t.topic.to_string(), serde_json::json!(n))).collect();
        Ok(serde_json::json!({ "file": self.path, "messages": per }))
    }
}

/// The MCAP recorder as a pipeline sink (stats key `mcap`), with the topics of `set`.
pub fn sink(path: &Path, queue: usize, blocking: bool, set: TopicSet) -> abvs_runtime_core::error::Result<Ros2OutSink> {
    Ros2OutSink::new("mcap", McapWriter::create(path, set)?, queue, blocking)
}
