//! Depth maps and point clouds to other processes on this computer over iceoryx2 shared memory, zero-copy.
//!
//! # Services
//!
//! | service | payload | user header | event service |
//! | --- | --- | --- | --- |
//! | `{prefix}/depth` | `[f32]`: row-major depth (m), `width * height` values, NaN = invalid | [`FrameHeader`] | `{prefix}/depth/event` |
//! | `{prefix}/cloud` | `[CloudPoint]`: valid points only (m, left home camera frame) | [`FrameHeader`] | `{prefix}/cloud/event` |
//!
//! `prefix` is `abvs` unless [`BridgeConfig::prefix`] says otherwise (tests use a unique one). After every
//! sample the publisher notifies the event service, so subscribers sleep in the kernel until a sample is
//! there ([`Subscriber::wait`]) instead of polling (on a loaded 2-core computer polling loses samples).
//!
//! # The one configuration
//!
//! Both sides build their services from the same [`BridgeConfig`]: the first process to open a service
//! fixes its static settings, and an opener whose settings do not fit fails. [`BridgeConfig::default`]:
//!
//! | setting | value | why |
//! | --- | --- | --- |
//! | `max_width` x `max_height` | 640 x 480 | the network resolution: sizes the publisher's shared-memory segment (depth 1.2 MB, cloud 4.9 MB a sample) |
//! | `max_subscribers` | 8 | viewers, recorders, planners on one robot |
//! | `subscriber_buffer` | 2 | a consumer a frame behind still gets it; older frames are stale anyway |
//! | `subscriber_max_borrowed` | 2 | a consumer may hold the previous frame while it takes the next |
//! | `history` | 1 | a late joiner gets the latest sample at once (on the publisher's next send) |
//! | safe overflow | on | a full subscriber buffer drops its oldest sample: a slow or dead subscriber never blocks the publisher |
//! | `max_publishers` | 1 | one runtime publishes; a second one is refused |
//! | `max_nodes` | 20 | processes that may open a service at once |
//!
//! The publisher preallocates `max_subscribers * (subscriber_buffer + subscriber_max_borrowed) + history + 1`
//! samples (34 with the defaults: ~42 MB of shared memory for depth, ~167 MB for the cloud at 640 x 480,
//! pages touched only as used), so a loan never fails however the subscribers behave, including a
//! subscriber killed while it holds samples. Because the pages are taken when first written, a publisher
//! checks at creation that /dev/shm has room for all of them ([`check_shm_space`]): on a full /dev/shm a
//! later write would kill the process with SIGBUS. Stale resources of crashed processes are removed when a node
//! is created ([`Publisher::new`], [`Subscriber::new`]) and by [`Publisher::cleanup_dead_nodes`].
//!
//! # Publishing
//!
//! The caller writes straight into the loaned shared-memory slice ([`Publisher::publish_depth`],
//! [`Publisher::publish_cloud`]) through a [`SampleWriter`]: it appends elements and counts them itself, and
//! every element it did not write is sent as [`BridgePayload::INVALID`] (NaN), so no call, whatever its
//! closure does, can send memory nobody wrote. Nothing is allocated per sample in steady state. A subscriber
//! that is slow, dead or late never makes a publish fail: publish returns `Ok` and counts what was unusual
//! in [`PublishStats`]. Errors are for the caller's mistakes (a sample larger than configured or than its
//! header says, a fill that writes past the sample) and broken shared memory.
//!
//! # Receiving
//!
//! A subscriber checks every sample against its header before handing it out: a depth payload must hold
//! exactly `width x height` values, a cloud at most `width x height` points and at least `valid`. A sample
//! that does not (only a foreign publisher can send one) is dropped and counted
//! ([`SubscribeStats::malformed`]).
//!
//! # Other processes
//!
//! iceoryx2 services live in shared memory and files of this machine that every process of the same user
//! can open. Such a process can: subscribe (and so read every depth map and cloud); hold borrowed samples
//! up to `subscriber_max_borrowed` (the publisher's preallocation covers that); crash while holding them
//! (cleaned up at the next node creation); create `{prefix}/depth` before the runtime starts, or take its
//! one publisher slot. It cannot make the runtime block, send memory nobody wrote, or go unnoticed when it
//! holds the service: a service found with settings other than this [`BridgeConfig`]'s
//! ([`BridgeError::Foreign`]) or with its publisher slot taken ([`BridgeError::PublisherTaken`]) is refused
//! with an error that says so (and names the holding process). A process that holds the publisher slot
//! and sends well-formed samples is indistinguishable from the runtime: iceoryx2 offers no access control
//! beyond file permissions, so a robot that must exclude that runs the runtime as its own user or uses a
//! private prefix.
use core::fmt::Debug;
use std::mem::MaybeUninit;
use std::time::{Duration, Instant};

use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher as IoxPublisher;
use iceoryx2::port::subscriber::Subscriber as IoxSubscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::port::LoanError;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;

/// The runtime's one clock (CLOCK_MONOTONIC ns), re-exported where the bridge's users have always found it.
pub use crate::messages::monotonic_ns;

/// The iceoryx2 service flavour of both sides: inter-process, ports usable from any thread.
pub type Ipc = ipc_threadsafe::Service;

/// The `frame_id` of every sample: points are in the left eye's home camera frame (OpenCV axes, metres).
pub const FRAME_ID: &str = "left_home_camera";

/// User header of both services: what the sample is, when it was seen and sent, and the geometry it was
/// computed with. iceoryx2 matches types by name, size and alignment: the name `abvs::FrameHeader/1` (and
/// `abvs::CloudPoint/1`) must change with the layout, so an old subscriber is refused instead of misreading.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("abvs::FrameHeader/1")]
pub struct FrameHeader {
    /// Pipeline frame sequence.
    pub seq: u64,
    /// Left frame mid-exposure time, CLOCK_MONOTONIC ns (latency = now - this).
    pub t_frame_ns: i64,
    /// CLOCK_MONOTONIC ns when the sample was sent (set by the publisher).
    pub t_publish_ns: i64,
    /// NUL-padded ASCII, [`FRAME_ID`].
    pub frame_id: [u8; 32],
    /// Calibrated FK pose of the left camera relative to its home: [alpha, beta, gamma] deg (Fick), [x, y, z] mm.
    pub pose_left: [f64; 6],
    /// Same for the right eye.
    pub pose_right: [f64; 6],
    /// fx, fy, cx, cy of the rectified left image (pixels) the depth map is in.
    pub intrinsics: [f64; 4],
    /// Depth map width (cloud: organised width; points may be fewer).
    pub width: u32,
    /// Depth map height (cloud: organised height).
    pub height: u32,
    /// Stereo baseline, metres.
    pub baseline_m: f64,
    /// Number of valid depth pixels / points (for a cloud: set by the publisher to the points written).
    pub valid: u32,
    /// Reserved for flags, 0 so far.
    pub flags: u32,
}

impl FrameHeader {
    /// `frame_id` as a string (up to the first NUL).
    pub fn frame_id_str(&self) -> &str {
        let n = self.frame_id.iter().position(|&b| b == 0).unwrap_or(self.frame_id.len());
        std::str::from_utf8(&self.frame_id[..n]).unwrap_or("")
    }

    /// Sets `frame_id` (NUL-padded, truncated to 31 bytes).
    pub fn set_frame_id(&mut self, id: &str) {
        self.frame_id = [0; 32];
        let n = id.len().min(31);
        self.frame_id[..n].copy_from_slice(&id.as_bytes()[..n]);
    }

    /// A header with `frame_id` = [`FRAME_ID`], everything else zero.
    pub fn new_left_home() -> Self {
        let mut h = Self::default();
        h.set_frame_id(FRAME_ID);
        h
    }
}

/// One point of the cloud: metres in the left home camera frame, colour as 0xAABBGGRR little-endian RGBA bytes.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("abvs::CloudPoint/1")]
pub struct CloudPoint {
    pub x: f32,
    pub y: f32,
    pub z: f32,
    pub rgba: u32,
}

/// A payload element of a bridge service.
pub trait BridgePayload: Copy + Debug + ZeroCopySend + Send + Sync + 'static {
    /// The service's name under the prefix.
    const TOPIC: &'static str;
    /// Written into loaned elements the caller did not fill.
    const INVALID: Self;
    /// Whether a received slice is cut to `header.valid` elements (the cloud) or kept whole (depth).
    const TRIM_TO_VALID: bool;
}

impl BridgePayload for f32 {
    const TOPIC: &'static str = "depth";
    const INVALID: Self = f32::NAN;
    const TRIM_TO_VALID: bool = false;
}

impl BridgePayload for CloudPoint {
    const TOPIC: &'static str = "cloud";
    const INVALID: Self = CloudPoint { x: f32::NAN, y: f32::NAN, z: f32::NAN, rgba: 0 };
    const TRIM_TO_VALID: bool = true;
}

/// The one configuration of both sides (see the module docs for the values and why).
#[derive(Debug, Clone, PartialEq)]
pub struct BridgeConfig {
    /// Service name prefix: services are `{prefix}/depth`, `{prefix}/cloud` and their `/event`s.
    pub prefix: String,
    /// Largest depth map / organised cloud width the publisher sends (network resolution).
    pub max_width: u32,
    /// Largest height.
    pub max_height: u32,
    pub max_subscribers: usize,
    pub subscriber_buffer: usize,
    pub subscriber_max_borrowed: usize,
    pub history: usize,
    pub max_publishers: usize,
    pub max_nodes: usize,
}

impl Default for BridgeConfig {
    fn default() -> Self {
        Self {
            prefix: "abvs".into(),
            max_width: 640,
            max_height: 480,
            max_subscribers: 8,
            subscriber_buffer: 2,
            subscriber_max_borrowed: 2,
            history: 1,
            max_publishers: 1,
            max_nodes: 20,
        }
    }
}

impl BridgeConfig {
    /// The defaults with another network resolution.
    pub fn for_resolution(width: u32, height: u32) -> Self {
        Self { max_width: width, max_height: height, ..Self::default() }
    }

    /// The same configuration under another service name prefix.
    pub fn with_prefix(mut self, prefix: impl Into<String>) -> Self {
        self.prefix = prefix.into();
        self
    }

    /// Largest number of elements in one sample (depth pixels or cloud points).
    pub fn max_elements(&self) -> usize {
        self.max_width as usize * self.max_height as usize
    }

    /// Samples a publisher preallocates: `max_subscribers * (subscriber_buffer + subscriber_max_borrowed) +
    /// history + 1`, so a loan never fails whatever the subscribers do.
    pub fn publisher_samples(&self) -> usize {
        self.max_subscribers * (self.subscriber_buffer + self.subscriber_max_borrowed) + self.history + 1
    }

    /// Shared memory a publisher of `T` takes once every sample was written: each preallocated sample at
    /// the largest size with its header, plus 1 MiB for iceoryx2's management (an estimate from above).
    pub fn publisher_bytes<T: BridgePayload>(&self) -> u64 {
        let sample =
            self.max_elements() as u64 * std::mem::size_of::<T>() as u64 + std::mem::size_of::<FrameHeader>() as u64;
        self.publisher_samples() as u64 * sample + (1 << 20)
    }

    /// Name of the publish-subscribe service of a topic ("depth" or "cloud").
    pub fn service_name(&self, topic: &str) -> String {
        format!("{}/{}", self.prefix, topic)
    }

    /// Name of the event service that is notified after every sample of a topic.
    pub fn event_name(&self, topic: &str) -> String {
        format!("{}/{}/event", self.prefix, topic)
    }

    fn check(&self) -> Result<(), BridgeError> {
        let bad = |what: &str| Err(BridgeError::Config(what.to_string()));
        if self.max_elements() == 0 {
            return bad("max_width x max_height is 0");
        }
        if self.max_subscribers == 0 || self.subscriber_buffer == 0 || self.max_publishers == 0 {
            return bad("max_subscribers, subscriber_buffer and max_publishers must be at least 1");
        }
        if self.subscriber_max_borrowed == 0 || self.max_nodes < 2 {
            return bad("subscriber_max_borrowed must be at least 1 and max_nodes at least 2");
        }
        if self.history > self.subscriber_buffer {
            return bad("history must not exceed subscriber_buffer");
        }
        Ok(())
    }
}

/// What went wrong, naming the service.
#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    #[error("iceoryx2 bridge configuration: {0}")]
    Config(String),
    /// An iceoryx2 call failed: `what` was being done on `service`.
    #[error("{service}: {what} failed: {detail}")]
    Iceoryx { service: String, what: &'static str, detail: String },
    /// The caller asked for a sample larger than the configured maximum.
    #[error("{service}: {n} elements exceed the configured maximum of {max} (BridgeConfig max_width x max_height)")]
    TooLarge { service: String, n: usize, max: usize },
    /// A depth payload whose size does not match the header's width x height.
    #[error("{service}: header says {width}x{height} but {max} elements fit")]
    BadSize { service: String, width: u32, height: u32, max: usize },
    /// The fill tried to write more elements than the sample holds (nothing was sent).
    #[error("{service}: the fill wrote past the sample's {capacity} elements; nothing was sent")]
    Overflow { service: String, capacity: usize },
    /// The service exists with static settings other than this side's [`BridgeConfig`]: another process
    /// created it differently.
    #[error(
        "{service}: the service exists with other settings than this process's BridgeConfig ({diffs}): \
         another process created it; stop that process or use another service prefix"
    )]
    Foreign { service: String, diffs: String },
    /// The publisher's shared memory would not fit in /dev/shm (too small, or filled by others).
    #[error(
        "{service}: needs {needed_mb:.1} MB of shared memory in {dir}, {free_mb:.1} MB free: make room there \
         (its pages are taken when first written, so a publisher that does not fit would be killed by SIGBUS \
         at a later publish) or lower the network resolution"
    )]
    SharedMemory { service: String, dir: String, needed_mb: f64, free_mb: f64 },
    /// Another publisher holds the service's one publisher slot.
    #[error(
        "{service}: another publisher holds the service's only publisher slot ({holders}); \
         stop that process (is another abvs publishing already?) or use another service prefix"
    )]
    PublisherTaken { service: String, holders: String },
}

fn iox<'a, E: Debug>(service: &'a str, what: &'static str) -> impl FnOnce(E) -> BridgeError + 'a {
    move |e| BridgeError::Iceoryx { service: service.to_string(), what, detail: format!("{e:?}") }
}

fn node(cfg: &BridgeConfig, role: &str) -> Result<(Node<Ipc>, u64), BridgeError> {
    // iceoryx2 warns on every start that no config file was loaded (its defaults are what we use);
    // errors only, unless IOX2_LOG_LEVEL says otherwise
    static LOG_LEVEL: std::sync::Once = std::sync::Once::new();
    LOG_LEVEL.call_once(|| set_log_level_from_env_or(LogLevel::Error));
    let service = cfg.service_name(role);
    let name = NodeName::new(&format!("abvs-{role}")).map_err(iox(&service, "naming the node"))?;
    // iceoryx2 would remove dead nodes inside `create` without saying how many: that is done below instead,
    // counted (the counts are in PublishStats and SubscribeStats)
    let mut config = Config::global_config().clone();
    config.global.node.cleanup_dead_nodes_on_creation = false;
    let node = NodeBuilder::new()
        .config(&config)
        .name(&name)
        // a library must not take over SIGINT/SIGTERM from the program it runs in
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<Ipc>()
        .map_err(iox(&service, "creating the iceoryx2 node"))?;
    // resources of processes that died (killed, crashed) are removed here, so a restart works
    let cleaned = node.try_cleanup_dead_nodes().cleanups;
    Ok((node, cleaned))
}

/// Where POSIX shared memory, and so iceoryx2's data segments, lives on Linux.
pub const SHM_DIR: &str = "/dev/shm";

/// Bytes free for this user in the filesystem at `dir` (statvfs), `None` where it cannot be read.
pub fn free_bytes(dir: &std::path::Path) -> Option<u64> {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(dir.as_os_str().as_bytes()).ok()?;
    let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: a NUL-terminated path and a statvfs we own.
    if unsafe { libc::statvfs(c.as_ptr(), &mut st) } != 0 {
        return None;
    }
    Some(st.f_bavail as u64 * st.f_frsize as u64)
}

/// Refuses `needed` bytes of publisher shared memory for `service` when /dev/shm has less free. A segment is
/// created sparse and takes its pages when first written, so a publisher that does not fit would start fine
/// and be killed by SIGBUS at a later publish. (/dev/shm filled by others after the check is not covered.)
pub fn check_shm_space(service: &str, needed: u64) -> Result<(), BridgeError> {
    let dir = std::path::Path::new(SHM_DIR);
    match free_bytes(dir) {
        Some(free) if free < needed => Err(BridgeError::SharedMemory {
            service: service.to_string(),
            dir: SHM_DIR.to_string(),
            needed_mb: needed as f64 / 1048576.0,
            free_mb: free as f64 / 1048576.0,
        }),
        _ => Ok(()),
    }
}

/// Process ids of iceoryx2 nodes on this machine whose process died without cleaning up (a crash, a kill).
/// Their resources are removed by the next node creation or [`Publisher::cleanup_dead_nodes`].
pub fn dead_node_pids() -> Result<Vec<i32>, BridgeError> {
    use iceoryx2::node::NodeView;
    let mut pids = Vec::new();
    Node::<Ipc>::list(Config::global_config(), |state| {
        if let NodeState::Dead(view) = state {
            pids.push(view.details().as_ref().map_or(-1, |d| d.process_id().value()));
        }
        CallbackProgression::Continue
    })
    .map_err(iox("iceoryx2 nodes", "listing the nodes"))?;
    Ok(pids)
}

type PubSubFactory<T> = iceoryx2::service::port_factory::publish_subscribe::PortFactory<Ipc, [T], FrameHeader>;
type EventFactory = iceoryx2::service::port_factory::event::PortFactory<Ipc>;

fn open_services<T: BridgePayload>(
    node: &Node<Ipc>,
    cfg: &BridgeConfig,
    service: &str,
) -> Result<(PubSubFactory<T>, EventFactory), BridgeError> {
    let name = ServiceName::new(service).map_err(iox(service, "naming the service"))?;
    let pubsub = node
        .service_builder(&name)
        .publish_subscribe::<[T]>()
        .user_header::<FrameHeader>()
        .max_publishers(cfg.max_publishers)
        .max_subscribers(cfg.max_subscribers)
        .subscriber_max_buffer_size(cfg.subscriber_buffer)
        .subscriber_max_borrowed_samples(cfg.subscriber_max_borrowed)
        .history_size(cfg.history)
        .enable_safe_overflow(true)
        .max_nodes(cfg.max_nodes)
        .open_or_create()
        .map_err(iox(
            service,
            "opening or creating the publish-subscribe service (settings must match the other side's BridgeConfig)",
        ))?;
    check_pubsub_settings(service, pubsub.static_config(), cfg)?;
    let ev_name_s = cfg.event_name(T::TOPIC);
    let ev_name = ServiceName::new(&ev_name_s).map_err(iox(service, "naming the event service"))?;
    let event = node
        .service_builder(&ev_name)
        .event()
        .max_notifiers(cfg.max_publishers)
        .max_listeners(cfg.max_subscribers)
        .max_nodes(cfg.max_nodes)
        .open_or_create()
        .map_err(iox(service, "opening or creating the event service"))?;
    let e = event.static_config();
    let diffs = differences(&[
        ("event max_notifiers", e.max_notifiers(), cfg.max_publishers),
        ("event max_listeners", e.max_listeners(), cfg.max_subscribers),
        ("event max_nodes", e.max_nodes(), cfg.max_nodes),
    ]);
    if !diffs.is_empty() {
        return Err(BridgeError::Foreign { service: ev_name_s, diffs });
    }
    Ok((pubsub, event))
}

/// "name found (expected x), ..." for every setting that differs.
fn differences(s: &[(&str, usize, usize)]) -> String {
    let d: Vec<String> =
        s.iter().filter(|(_, a, b)| a != b).map(|(n, found, want)| format!("{n} {found} (expected {want})")).collect();
    d.join(", ")
}

/// iceoryx2 opens an existing service whose limits are at least the requested ones; the bridge needs exactly
/// its own (e.g. a service created with 4 publisher slots would let a second process publish next to the
/// runtime), so anything else is refused.
fn check_pubsub_settings(
    service: &str,
    c: &iceoryx2::service::static_config::publish_subscribe::StaticConfig,
    cfg: &BridgeConfig,
) -> Result<(), BridgeError> {
    let mut diffs = differences(&[
        ("max_publishers", c.max_publishers(), cfg.max_publishers),
        ("max_subscribers", c.max_subscribers(), cfg.max_subscribers),
        ("subscriber_buffer", c.subscriber_max_buffer_size(), cfg.subscriber_buffer),
        ("subscriber_max_borrowed", c.subscriber_max_borrowed_samples(), cfg.subscriber_max_borrowed),
        ("history", c.history_size(), cfg.history),
        ("max_nodes", c.max_nodes(), cfg.max_nodes),
    ]);
    if !c.has_safe_overflow() {
        diffs += if diffs.is_empty() { "" } else { ", " };
        diffs += "safe overflow off (expected on)";
    }
    if diffs.is_empty() {
        Ok(())
    } else {
        Err(BridgeError::Foreign { service: service.to_string(), diffs })
    }
}

/// The processes holding a service's publisher ports, for the error that says the slot is taken.
fn publisher_holders<T: BridgePayload>(pubsub: &PubSubFactory<T>) -> String {
    let mut pids = Vec::new();
    pubsub.dynamic_config().list_publishers(|p| {
        pids.push(p.node_id.pid::<Ipc>().map(|pid| pid.value()).ok());
        CallbackProgression::Continue
    });
    let me = std::process::id() as i32;
    let names: Vec<String> = pids
        .into_iter()
        .map(|pid| match pid {
            Some(p) if p == me => format!("process {p}, this one"),
            Some(p) => match std::fs::read_to_string(format!("/proc/{p}/comm")) {
                Ok(c) => format!("process {p} `{}`", c.trim()),
                Err(_) => format!("process {p}"),
            },
            None => "a process of unknown id".to_string(),
        })
        .collect();
    if names.is_empty() {
        "held by a port being removed".to_string()
    } else {
        format!("held by {}", names.join(", "))
    }
}

/// What a publisher saw that was not a plain delivery. None of it makes a publish fail.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct PublishStats {
    /// Samples sent.
    pub published: u64,
    /// Sum over samples of the subscribers each was delivered to.
    pub deliveries: u64,
    /// Samples not sent because no shared-memory sample could be loaned (should stay 0 with the sizing).
    pub loan_failures: u64,
    /// Sends that reported a broken connection (e.g. a subscriber that died).
    pub send_failures: u64,
    /// Event notifications that failed.
    pub notify_failures: u64,
    /// Dead nodes (crashed processes) whose resources were removed.
    pub dead_nodes_cleaned: u64,
}

/// Publishes one topic: [`DepthPublisher`] or [`CloudPublisher`]. Create once at start-up.
pub struct Publisher<T: BridgePayload> {
    service: String,
    max: usize,
    stats: PublishStats,
    // field order is drop order: ports before the services and the node
    publisher: IoxPublisher<Ipc, [T], FrameHeader>,
    notifier: Notifier<Ipc>,
    _pubsub: PubSubFactory<T>,
    _event: EventFactory,
    node: Node<Ipc>,
}

/// Depth maps on `{prefix}/depth`.
pub type DepthPublisher = Publisher<f32>;
/// Point clouds on `{prefix}/cloud`.
pub type CloudPublisher = Publisher<CloudPoint>;

impl<T: BridgePayload> Publisher<T> {
    /// Opens (or creates) the topic's services with `config` and a publisher sized for
    /// `config.max_width x config.max_height` elements.
    pub fn new(config: &BridgeConfig) -> Result<Self, BridgeError> {
        config.check()?;
        let service = config.service_name(T::TOPIC);
        check_shm_space(&service, config.publisher_bytes::<T>())?;
        let (node, cleaned) = node(config, T::TOPIC)?;
        let (pubsub, event) = open_services::<T>(&node, config, &service)?;
        let max = config.max_elements();
        let publisher = pubsub
            .publisher_builder()
            .initial_max_slice_len(max)
            .allocation_strategy(AllocationStrategy::Static)
            .max_loaned_samples(1)
            .backpressure_strategy(BackpressureStrategy::DiscardData)
            .create()
            .map_err(|e| match e {
                iceoryx2::port::publisher::PublisherCreateError::ExceedsMaxSupportedPublishers => {
                    BridgeError::PublisherTaken { service: service.clone(), holders: publisher_holders(&pubsub) }
                }
                e => iox(&service, "creating the publisher")(e),
            })?;
        let notifier = event.notifier_builder().create().map_err(iox(&service, "creating the event notifier"))?;
        let stats = PublishStats { dead_nodes_cleaned: cleaned, ..Default::default() };
        Ok(Self { service, max, stats, publisher, notifier, _pubsub: pubsub, _event: event, node })
    }

    /// The publish-subscribe service's name.
    pub fn service_name(&self) -> &str {
        &self.service
    }

    /// Largest number of elements in one sample.
    pub fn capacity(&self) -> usize {
        self.max
    }

    /// What was counted so far.
    pub fn stats(&self) -> PublishStats {
        self.stats
    }

    /// Loans `n_max` elements, lets `fill` append to the front of them through a [`SampleWriter`], writes
    /// [`BridgePayload::INVALID`] into the rest, sets `header` (with `t_publish_ns` = now) as the user header,
    /// sends and notifies. Returns the number of subscribers the sample was delivered to. With
    /// `valid_from_fill`, `header.valid` becomes the number of elements written.
    fn publish_impl<F>(
        &mut self,
        header: &FrameHeader,
        n_max: usize,
        valid_from_fill: bool,
        fill: F,
    ) -> Result<usize, BridgeError>
    where
        F: FnOnce(&mut SampleWriter<'_, T>),
    {
        if n_max > self.max {
            return Err(BridgeError::TooLarge { service: self.service.clone(), n: n_max, max: self.max });
        }
        let mut sample = match self.publisher.loan_slice_uninit(n_max) {
            Ok(s) => s,
            Err(LoanError::OutOfMemory) | Err(LoanError::ExceedsMaxLoans) => {
                self.stats.loan_failures += 1;
                return Ok(0);
            }
            Err(e) => return Err(iox(&self.service, "loaning a sample")(e)),
        };
        let payload = sample.payload_mut();
        let base = payload.as_ptr();
        let mut writer = SampleWriter { buf: payload, len: 0, overflow: false };
        fill(&mut writer);
        let SampleWriter { buf, len: n, overflow } = writer;
        // The writer is the only way in and cannot be built outside this module; the pointer check makes sure
        // the one handed back is the one handed out (not another publish's, swapped in by a nested call).
        if overflow || !std::ptr::eq(buf.as_ptr(), base) || buf.len() != n_max || n > n_max {
            return Err(BridgeError::Overflow { service: self.service.clone(), capacity: n_max });
        }
        for p in &mut buf[n..] {
            p.write(T::INVALID);
        }
        // SAFETY: the writer wrote [..n] (it advances its count only after a `MaybeUninit::write`), the loop
        // above [n..]; both on this sample's payload (checked above).
        let mut sample = unsafe { sample.assume_init() };
        let uh = sample.user_header_mut();
        *uh = *header;
        if valid_from_fill {
            uh.valid = n as u32;
        }
        uh.t_publish_ns = monotonic_ns();
        let delivered = match sample.send() {
            Ok(k) => k,
            Err(_) => {
                self.stats.send_failures += 1;
                0
            }
        };
        self.stats.published += 1;
        self.stats.deliveries += delivered as u64;
        if self.notifier.notify().is_err() {
            self.stats.notify_failures += 1;
        }
        Ok(delivered)
    }

    /// Delivers the history to subscribers that joined since the last send and wakes them. The
    /// publisher does this on every send; call it when no sample is due for a while.
    pub fn update_connections(&mut self) -> Result<(), BridgeError> {
        self.publisher.update_connections().map_err(iox(&self.service, "updating connections"))?;
        if self.notifier.notify().is_err() {
            self.stats.notify_failures += 1;
        }
        Ok(())
    }

    /// Removes the resources of dead nodes (crashed or killed processes) on this machine; returns how many.
    /// Done at start-up; call it now and then (e.g. once a second) in a long run.
    pub fn cleanup_dead_nodes(&mut self) -> u64 {
        let n = self.node.try_cleanup_dead_nodes().cleanups;
        self.stats.dead_nodes_cleaned += n;
        n
    }
}

/// Where a publish's fill writes: the front of the loaned shared-memory slice, one element after the other.
/// It counts what was written; the publisher sends every element it did not write as
/// [`BridgePayload::INVALID`]. Only the publisher makes one.
///
/// The count is the writer's, so a fill cannot claim elements it did not write (the misuse the previous
/// API allowed, a fill that reports 100 points and writes none, does not compile):
/// ```compile_fail
/// # use abvs_runtime::bridges::iceoryx::*;
/// # fn f(p: &mut CloudPublisher, h: &FrameHeader) {
/// p.publish_cloud(h, 100, |_| 100).unwrap();
/// # }
/// ```
/// and a writer cannot be made outside the publisher:
/// ```compile_fail
/// # use abvs_runtime::bridges::iceoryx::*;
/// let mut buf = [std::mem::MaybeUninit::<f32>::uninit(); 4];
/// let w = SampleWriter { buf: &mut buf[..], len: 4, overflow: false };
/// ```
/// while this is how a fill writes:
/// ```no_run
/// # use abvs_runtime::bridges::iceoryx::*;
/// # fn f(p: &mut CloudPublisher, h: &FrameHeader, pts: &[CloudPoint]) {
/// p.publish_cloud(h, pts.len(), |w| w.extend_from_slice(pts)).unwrap();
/// # }
/// ```
pub struct SampleWriter<'a, T> {
    buf: &'a mut [MaybeUninit<T>],
    len: usize,
    overflow: bool,
}

impl<T: Copy> SampleWriter<'_, T> {
    /// Elements the sample holds.
    pub fn capacity(&self) -> usize {
        self.buf.len()
    }

    /// Elements written so far.
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Appends one element. Past the capacity nothing is written, `false` is returned and the publish fails
    /// with [`BridgeError::Overflow`] (nothing is sent).
    #[inline]
    pub fn push(&mut self, v: T) -> bool {
        match self.buf.get_mut(self.len) {
            Some(slot) => {
                slot.write(v);
                self.len += 1;
                true
            }
            None => {
                self.overflow = true;
                false
            }
        }
    }

    /// Appends all of `src`. What does not fit is not written and makes the publish fail, as [`Self::push`].
    pub fn extend_from_slice(&mut self, src: &[T]) {
        let room = self.buf.len() - self.len;
        if src.len() > room {
            self.overflow = true;
        }
        let n = src.len().min(room);
        for (d, s) in self.buf[self.len..self.len + n].iter_mut().zip(src) {
            d.write(*s);
        }
        self.len += n;
    }
}

impl Publisher<f32> {
    /// Publishes a depth map of `header.width x header.height` (row-major, metres, NaN = invalid): `fill`
    /// writes it through the [`SampleWriter`] into the loaned shared memory (elements not written are NaN).
    /// `header.valid` is sent as given.
    pub fn publish_depth<F>(&mut self, header: &FrameHeader, fill: F) -> Result<usize, BridgeError>
    where
        F: FnOnce(&mut SampleWriter<'_, f32>),
    {
        let n = (header.width as usize).saturating_mul(header.height as usize);
        if n > self.max {
            return Err(BridgeError::BadSize {
                service: self.service.clone(),
                width: header.width,
                height: header.height,
                max: self.max,
            });
        }
        self.publish_impl(header, n, false, fill)
    }
}

impl Publisher<CloudPoint> {
    /// Publishes a cloud of at most `n_max` points (at most the header's organised `width x height`): `fill`
    /// writes the valid points through the [`SampleWriter`] to the front of the loaned shared-memory slice
    /// (`header.valid` is set to how many it wrote). The sample carries `n_max` elements, the unused tail
    /// set to NaN: pass the exact count when it is known (e.g. the valid depth pixels) to save that fill.
    pub fn publish_cloud<F>(&mut self, header: &FrameHeader, n_max: usize, fill: F) -> Result<usize, BridgeError>
    where
        F: FnOnce(&mut SampleWriter<'_, CloudPoint>),
    {
        let organised = (header.width as usize).saturating_mul(header.height as usize);
        if n_max > organised {
            return Err(BridgeError::TooLarge { service: self.service.clone(), n: n_max, max: organised });
        }
        self.publish_impl(header, n_max, true, fill)
    }
}

/// What a subscriber saw.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SubscribeStats {
    /// Samples received.
    pub received: u64,
    /// Gaps in `seq` between consecutive samples (dropped by safe overflow or not published).
    pub seq_gaps: u64,
    /// Samples whose `seq` is not after the previous one's: a publisher that restarted (its sequence starts
    /// again) while this subscriber stayed up.
    pub seq_restarts: u64,
    /// Dead nodes whose resources were removed when this subscriber started.
    pub dead_nodes_cleaned: u64,
    /// Samples dropped because the payload did not fit the header (not `width x height` depth values, a
    /// cloud longer than `width x height` or shorter than `valid`).
    pub malformed: u64,
}

/// One received sample: the header and the payload, read in place in shared memory. Dropping it returns
/// the sample to the publisher; hold at most `subscriber_max_borrowed` (2) at a time.
pub struct Received<T: BridgePayload> {
    sample: Sample<Ipc, [T], FrameHeader>,
}

impl<T: BridgePayload> Received<T> {
    /// The frame header.
    pub fn header(&self) -> &FrameHeader {
        self.sample.user_header()
    }

    /// The payload: the whole depth map (width x height), or the cloud's valid points.
    pub fn data(&self) -> &[T] {
        let p = self.sample.payload();
        if T::TRIM_TO_VALID {
            &p[..(self.header().valid as usize).min(p.len())]
        } else {
            p
        }
    }
}

/// Whether a received payload of `len` elements fits its header: depth `width x height` exactly, a cloud at
/// most that and at least `valid`.
pub fn payload_fits<T: BridgePayload>(h: &FrameHeader, len: usize) -> bool {
    let Some(organised) = (h.width as usize).checked_mul(h.height as usize) else { return false };
    let valid_ok = (h.valid as usize) <= len;
    if T::TRIM_TO_VALID {
        valid_ok && len <= organised
    } else {
        valid_ok && len == organised
    }
}

/// Receives one topic: [`DepthSubscriber`] or [`CloudSubscriber`].
pub struct Subscriber<T: BridgePayload> {
    service: String,
    stats: SubscribeStats,
    last_seq: Option<u64>,
    subscriber: IoxSubscriber<Ipc, [T], FrameHeader>,
    listener: Listener<Ipc>,
    _pubsub: PubSubFactory<T>,
    _event: EventFactory,
    _node: Node<Ipc>,
}

/// Depth maps from `{prefix}/depth`.
pub type DepthSubscriber = Subscriber<f32>;
/// Point clouds from `{prefix}/cloud`.
pub type CloudSubscriber = Subscriber<CloudPoint>;

impl<T: BridgePayload> Subscriber<T> {
    /// Opens (or creates, if no publisher is there yet) the topic's services with `config`.
    pub fn new(config: &BridgeConfig) -> Result<Self, BridgeError> {
        config.check()?;
        let service = config.service_name(T::TOPIC);
        let (node, cleaned) = node(config, T::TOPIC)?;
        let (pubsub, event) = open_services::<T>(&node, config, &service)?;
        let subscriber = pubsub
            .subscriber_builder()
            .buffer_size(config.subscriber_buffer)
            .create()
            .map_err(iox(&service, "creating the subscriber"))?;
        let listener = event.listener_builder().create().map_err(iox(&service, "creating the event listener"))?;
        let stats = SubscribeStats { dead_nodes_cleaned: cleaned, ..Default::default() };
        Ok(Self { service, stats, last_seq: None, subscriber, listener, _pubsub: pubsub, _event: event, _node: node })
    }

    /// The publish-subscribe service's name.
    pub fn service_name(&self) -> &str {
        &self.service
    }

    /// What was counted so far.
    pub fn stats(&self) -> SubscribeStats {
        self.stats
    }

    /// Takes the next sample without waiting. A sample whose payload does not fit its header is dropped
    /// and counted ([`SubscribeStats::malformed`]); the next one is taken instead.
    pub fn try_receive(&mut self) -> Result<Option<Received<T>>, BridgeError> {
        loop {
            let Some(sample) = self.subscriber.receive().map_err(iox(&self.service, "receiving"))? else {
                return Ok(None);
            };
            let h = sample.user_header();
            if !payload_fits::<T>(h, sample.payload().len()) {
                self.stats.malformed += 1;
                continue;
            }
            let seq = h.seq;
            if let Some(last) = self.last_seq {
                if seq > last.saturating_add(1) {
                    self.stats.seq_gaps += 1;
                } else if seq <= last {
                    self.stats.seq_restarts += 1;
                }
            }
            self.last_seq = Some(seq);
            self.stats.received += 1;
            return Ok(Some(Received { sample }));
        }
    }

    /// Waits up to `timeout` for the next sample, asleep on the event service between samples.
    /// `Ok(None)`: nothing arrived in time.
    pub fn wait(&mut self, timeout: Duration) -> Result<Option<Received<T>>, BridgeError> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(r) = self.try_receive()? {
                // consume the notification(s) of what is being taken now
                let _ = self.listener.try_wait(|_| {});
                return Ok(Some(r));
            }
            let now = Instant::now();
            if now >= deadline {
                return Ok(None);
            }
            // A notification that came after the receive above is kept by the listener, so the wait returns
            // at once. The 100 ms cap only bounds the delay of a late joiner's history (delivered by the
            // publisher without a notification if it calls no update_connections).
            let slice = (deadline - now).min(Duration::from_millis(100));
            self.listener.timed_wait(|_| {}, slice).map_err(iox(&self.service, "waiting on the event listener"))?;
        }
    }
}
