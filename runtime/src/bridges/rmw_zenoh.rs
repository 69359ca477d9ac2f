//! The rmw_zenoh wire format: what a ROS 2 node on `rmw_zenoh_cpp` publishes, so that `ros2 topic list`
//! and `ros2 topic echo` on such a system see the runtime's topics without zenoh-bridge-ros2dds
//! (ros2/rmw_zenoh: docs/design.md, `liveliness_utils.cpp`, `attachment_helpers.cpp`):
//!
//! - data key `<domain>/<topic without leading slash>/<pkg>::msg::dds_::<Type>_/<type hash>`
//!   ([`topic_key`]), the type hash RIHS01 from Iron on and `TypeHashNotSupported` on Humble ([`RosDistro`]);
//! - a liveliness token per entity ([`Node::token`]): the node itself (`NN`) and each publisher (`MP`) or
//!   subscription (`MS`), `@ros2_lv/<domain>/<session zid>/<node id>/<entity id>/<kind>/<enclave>/
//!   <namespace>/<node>[/<topic>/<type>/<hash>/<qos>]`, every name with its `/` written `%`;
//! - on every sample a 33-byte attachment ([`attachment`]): sequence number (i64 LE, from 1, +1 a sample),
//!   the source timestamp (i64 LE, ns since the Unix epoch), then the publisher's 16-byte GID as a
//!   Zenoh-serialised sequence (its length 16 = 0x10, then the bytes).
//!
//! The QoS in a token is rmw's enum values ([`Qos::encode`]); the runtime's publishers are sensor data
//! (best effort, volatile, keep last 5: rclcpp's `SensorDataQoS`), what `ros2 topic echo` and rviz
//! subscribe with for images and clouds.
use sha2::{Digest, Sha256};
use zenoh::liveliness::LivelinessToken;
use zenoh::{Session, Wait};

use abvs_runtime_core::config::RosDistro;

use crate::ros2::Topic;

/// The hash field of `topic`'s keys and tokens under `distro`.
pub fn type_hash(distro: RosDistro, topic: &Topic) -> &'static str {
    match distro {
        RosDistro::Humble => "TypeHashNotSupported",
        RosDistro::Jazzy | RosDistro::Kilted => topic.rihs01,
    }
}

/// The kind of a ROS 2 graph entity, as its token names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EntityKind {
    /// The node itself (`NN`).
    Node,
    /// A publisher (`MP`).
    Publisher,
    /// A subscription (`MS`).
    Subscription,
}

impl EntityKind {
    fn as_str(self) -> &'static str {
        match self {
            EntityKind::Node => "NN",
            EntityKind::Publisher => "MP",
            EntityKind::Subscription => "MS",
        }
    }
}

/// An endpoint's QoS as a token carries it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Qos {
    /// Reliable (else best effort).
    pub reliable: bool,
    /// Transient local (else volatile).
    pub transient_local: bool,
    /// Keep-last depth.
    pub depth: u32,
}

impl Qos {
    /// Sensor data: best effort, volatile, keep last 5 (rclcpp `SensorDataQoS`).
    pub const SENSOR_DATA: Qos = Qos { reliable: false, transient_local: false, depth: 5 };

    /// `<reliability>:<durability>:<history>,<depth>:<deadline s>,<ns>:<lifespan s>,<ns>:<liveliness>,<lease
    /// s>,<ns>` with rmw's enum values (reliable 1, best effort 2; transient local 1, volatile 2; keep last
    /// 1). Deadline, lifespan and liveliness are left empty: rmw_zenoh reads an empty field as its default
    /// (infinite, automatic), which is what the runtime has.
    pub fn encode(&self) -> String {
        let reliability = if self.reliable { 1 } else { 2 };
        let durability = if self.transient_local { 1 } else { 2 };
        format!("{reliability}:{durability}:1,{}:,:,:,,", self.depth)
    }
}

/// A ROS 2 name with its `/` written `%` (Zenoh keys have no empty chunks; rmw_zenoh's `mangle_name`).
pub fn mangle(name: &str) -> String {
    name.replace('/', "%")
}

/// The data key of `topic` (`/abvs/depth`) with type `dds_type` and hash `hash` in `domain`.
pub fn topic_key(domain: u32, topic: &str, dds_type: &str, hash: &str) -> String {
    format!("{domain}/{}/{dds_type}/{hash}", topic.trim_matches('/'))
}

/// One entity's keys: where its samples go, its liveliness token and its GID.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Endpoint {
    /// The data key ([`topic_key`]).
    pub key: String,
    /// The liveliness token's key.
    pub token: String,
    /// The GID samples carry in their attachment.
    pub gid: [u8; 16],
}

/// The runtime as a ROS 2 node on rmw_zenoh: names its entities, hands out their ids.
#[derive(Debug, Clone)]
pub struct Node {
    domain: u32,
    zid: String,
    namespace: String,
    name: String,
    next_id: u32,
}

/// The node's own id (rmw_zenoh numbers a context's entities from 0, the node first).
const NODE_ID: u32 = 0;

impl Node {
    /// The node `namespace`/`name` in `domain`, on the Zenoh session `zid` (`Session::zid().to_string()`).
    pub fn new(domain: u32, zid: String, namespace: &str, name: &str) -> Node {
        Node { domain, zid, namespace: namespace.into(), name: name.into(), next_id: NODE_ID + 1 }
    }

    fn prefix(&self, id: u32, kind: EntityKind) -> String {
        // the enclave is the root (`/`), as for any node started without one
        format!(
            "@ros2_lv/{}/{}/{NODE_ID}/{id}/{}/%/{}/{}",
            self.domain,
            self.zid,
            kind.as_str(),
            mangle(&self.namespace),
            mangle(&self.name)
        )
    }

    /// Numbers the next entities from `id` on (another part of the runtime declares entities on the same node:
    /// the ids stay unique).
    pub fn skip_to(&mut self, id: u32) {
        self.next_id = self.next_id.max(id);
    }

    /// The node's own token (`NN`).
    pub fn token(&self) -> String {
        self.prefix(NODE_ID, EntityKind::Node)
    }

    /// A new publisher or subscription of `topic` (type `dds_type`, hash `hash`) with `qos`: its keys and GID.
    pub fn endpoint(&mut self, kind: EntityKind, topic: &str, dds_type: &str, hash: &str, qos: Qos) -> Endpoint {
        let id = self.next_id;
        self.next_id += 1;
        let token = format!("{}/{}/{}/{hash}/{}", self.prefix(id, kind), mangle(topic), mangle(dds_type), qos.encode());
        // rmw_zenoh hashes the token into the GID (XXH3-128); any 16 bytes unique to the entity serve its
        // subscribers, which tell publishers apart by them
        let mut gid = [0u8; 16];
        gid.copy_from_slice(&Sha256::digest(token.as_bytes())[..16]);
        Endpoint { key: topic_key(self.domain, topic, dds_type, hash), token, gid }
    }

    /// [`Node::endpoint`] for one of the runtime's topics in `distro`, and its token declared on `session`:
    /// the one call a publisher or subscription needs to show up in the ROS 2 graph.
    pub fn declare(
        &mut self,
        session: &Session,
        kind: EntityKind,
        topic: &Topic,
        distro: RosDistro,
        qos: Qos,
    ) -> zenoh::Result<(Endpoint, LivelinessToken)> {
        let e = self.endpoint(kind, topic.topic, &topic.dds_type(), type_hash(distro, topic), qos);
        let token = session.liveliness().declare_token(e.token.clone()).wait()?;
        Ok((e, token))
    }
}

/// Bytes of a sample's attachment.
pub const ATTACHMENT_LEN: usize = 33;

/// The attachment of a sample: sequence number, source timestamp (ns since the Unix epoch), GID.
pub fn attachment(seq: i64, source_ns: i64, gid: &[u8; 16]) -> [u8; ATTACHMENT_LEN] {
    let mut a = [0u8; ATTACHMENT_LEN];
    a[..8].copy_from_slice(&seq.to_le_bytes());
    a[8..16].copy_from_slice(&source_ns.to_le_bytes());
    // a Zenoh-serialised byte sequence: its length as a LEB128 varint (one byte for 16), then the bytes
    a[16] = 16;
    a[17..].copy_from_slice(gid);
    a
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ros2::TOPICS;

    #[test]
    fn keys_tokens_and_attachment() {
        let depth = &TOPICS[0];
        assert_eq!(
            topic_key(0, depth.topic, &depth.dds_type(), type_hash(RosDistro::Jazzy, depth)),
            "0/abvs/depth/sensor_msgs::msg::dds_::Image_/\
             RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47"
        );
        assert_eq!(type_hash(RosDistro::Humble, depth), "TypeHashNotSupported");
        assert_eq!(type_hash(RosDistro::Kilted, &TOPICS[2]), type_hash(RosDistro::Jazzy, &TOPICS[2]));
        let mut n = Node::new(7, "a1b2".into(), "/", "abvs");
        assert_eq!(n.token(), "@ros2_lv/7/a1b2/0/0/NN/%/%/abvs");
        let tf = &TOPICS[3];
        let p = n.endpoint(EntityKind::Publisher, tf.topic, &tf.dds_type(), "TypeHashNotSupported", Qos::SENSOR_DATA);
        assert_eq!(
            p.token,
            "@ros2_lv/7/a1b2/0/1/MP/%/%/abvs/%tf/tf2_msgs::msg::dds_::TFMessage_/TypeHashNotSupported/2:2:1,5:,:,:,,"
        );
        assert_eq!(p.key, "7/tf/tf2_msgs::msg::dds_::TFMessage_/TypeHashNotSupported");
        // entity ids count up; a subscription is the same call; each entity its own GID
        let mut ns = Node::new(0, "z".into(), "/robot/head", "eyes");
        let q = Qos { reliable: true, transient_local: false, depth: 1 };
        let s =
            ns.endpoint(EntityKind::Subscription, "/abvs/gaze_goal", "geometry_msgs::msg::dds_::PointStamped_", "H", q);
        assert_eq!(
            s.token,
            "@ros2_lv/0/z/0/1/MS/%/%robot%head/eyes/%abvs%gaze_goal/geometry_msgs::msg::dds_::PointStamped_/H/1:2:1,1:,:,:,,"
        );
        let p2 = n.endpoint(EntityKind::Publisher, tf.topic, &tf.dds_type(), "TypeHashNotSupported", Qos::SENSOR_DATA);
        assert!(p2.token.contains("/0/2/MP/") && p2.gid != p.gid);
        // every token is a valid Zenoh key expression
        for k in [&n.token(), &p.token, &s.token, &p.key] {
            zenoh::key_expr::KeyExpr::try_from(k.as_str()).unwrap();
        }
        let a = attachment(3, -2, &p.gid);
        assert_eq!(a.len(), 33);
        assert_eq!(&a[..8], &3i64.to_le_bytes());
        assert_eq!(&a[8..16], &(-2i64).to_le_bytes());
        assert_eq!(a[16], 0x10);
        assert_eq!(&a[17..], &p.gid);
    }
}
