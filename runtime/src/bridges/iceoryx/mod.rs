//! Depth maps, their confidence and point clouds to other processes on this computer over iceoryx2 shared
//! memory, zero-copy.
//!
//! # Services
//!
//! | service | payload | user header | event service |
//! | --- | --- | --- | --- |
//! | `{prefix}/depth` | `[f32]`: row-major depth (m), `width * height` values, NaN = invalid | [`FrameHeader`] | `{prefix}/depth/event` |
//! | `{prefix}/confidence` | `[f32]`: row-major confidence of each depth pixel in [0, 1], `width * height` values, 0 = invalid; whenever the run computes it: by default with census-refine (its own confidence, `abvs_disparity::census_confidence`), or `[disparity] confidence` (the left-right check) | [`FrameHeader`] (the depth sample's, same `seq`) | `{prefix}/confidence/event` |
//! | `{prefix}/cloud` | `[CloudPoint]`: valid points only (m, left home camera frame) | [`FrameHeader`] | `{prefix}/cloud/event` |
//!
//! The confidence (census-refine's own by default, the validity mask's; with `[disparity] confidence`
//! `crate::tasks::confidence`: exp(-|left-right disparity disagreement|), 0 where the left-right check
//! fails) is published before the cloud of the same frame; match it to its depth map by
//! `seq`, never by arrival order (either subscriber may have dropped a sample).
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
//!
//! By concern: this module (the wire types, [`BridgeConfig`], [`BridgeError`]), `services` (nodes,
//! services and their checks, /dev/shm space, dead nodes), `publisher`, `subscriber`; [`gaze`]: the gaze
//! goals in and the gaze states out (`{prefix}/gaze/goal`, `{prefix}/gaze/state`).
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
use abvs_runtime_core::messages::monotonic_ns;

/// The iceoryx2 service flavour of both sides: inter-process, ports usable from any thread.
pub type Ipc = ipc_threadsafe::Service;

/// The `frame_id` of every sample: points are in the left eye's home camera frame (OpenCV axes, metres).
pub const FRAME_ID: &str = "left_home_camera";

/// [`FrameHeader::flags`] bit: the eyes moved too fast during this frame's exposure (a saccade): its depth
/// is all NaN and its cloud empty on purpose, not because the scene has no valid depth. A frame that never
/// arrives was lost instead: its `seq` is missing.
pub const FLAG_MOTION_GATED: u32 = 1;

/// Header flag of the fovea's services (`{prefix}/fovea/depth`, `{prefix}/fovea/cloud`): the window is on the
/// image centre at the default distance, not on a measured fixation (`tasks::fovea`).
pub const FLAG_FOVEA_DEFAULT_FIXATION: u32 = 2;

/// The fovea's topics sit under this one: `{prefix}/fovea/depth` and `{prefix}/fovea/cloud`. Their headers
/// carry the fovea's own intrinsics (native focal length; the principal point places the window in the main
/// map's rectified plane) and size.
pub const FOVEA_TOPIC: &str = "fovea";

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
    /// Bit flags: [`FLAG_MOTION_GATED`]; the other bits are 0.
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
    /// X (m, right).
    pub x: f32,
    /// Y (m, down).
    pub y: f32,
    /// Z (m, forward).
    pub z: f32,
    /// Colour: 0xAABBGGRR (gray here: the rectified left image's level, alpha 255).
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

/// The confidence's topic: `[f32]` like depth, on its own service ([`Publisher::confidence`],
/// [`Subscriber::confidence`]).
pub const CONFIDENCE_TOPIC: &str = "confidence";

impl BridgePayload for CloudPoint {
    const TOPIC: &'static str = "cloud";
    const INVALID: Self = CloudPoint { x: f32::NAN, y: f32::NAN, z: f32::NAN, rgba: 0 };
    const TRIM_TO_VALID: bool = true;
}

/// The one configuration of both sides (see the module docs for the values and why).
#[derive(Debug, Clone, PartialEq)]
pub struct BridgeConfig {
    /// Service name prefix: services are `{prefix}/depth`, `{prefix}/confidence`, `{prefix}/cloud` and their
    /// `/event`s.
    pub prefix: String,
    /// Largest depth map / organised cloud width the publisher sends (network resolution).
    pub max_width: u32,
    /// Largest height.
    pub max_height: u32,
    /// Subscribers a service admits.
    pub max_subscribers: usize,
    /// Samples a subscriber's queue holds before the oldest is dropped (safe overflow).
    pub subscriber_buffer: usize,
    /// Samples a subscriber may hold borrowed at once.
    pub subscriber_max_borrowed: usize,
    /// Samples a late joiner gets at once.
    pub history: usize,
    /// Publishers a service admits (one runtime).
    pub max_publishers: usize,
    /// Processes that may open a service at once.
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

    /// The iceoryx2 bridge of a deployment: `[bridges.iceoryx]`'s prefix, sized for the rectified resolution.
    /// A subscriber in another process opens its services with the same value ([`Subscriber::new`]); any
    /// other settings are refused as foreign.
    pub fn for_deployment(c: &abvs_runtime_core::config::RuntimeConfig) -> Self {
        Self::for_resolution(c.disparity.width, c.disparity.height)
            .with_prefix(c.bridges.iceoryx.service_prefix.clone())
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

    /// Name of the publish-subscribe service of a topic ("depth", "confidence" or "cloud").
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
    /// A [`BridgeConfig`] no service can have (a zero size or count).
    #[error("iceoryx2 bridge configuration: {0}")]
    Config(String),
    /// An iceoryx2 call failed: `what` was being done on `service`.
    #[error("{service}: {what} failed: {detail}")]
    Iceoryx {
        /// The service.
        service: String,
        /// What was being done.
        what: &'static str,
        /// What iceoryx2 said.
        detail: String,
    },
    /// The caller asked for a sample larger than the configured maximum.
    #[error("{service}: {n} elements exceed the configured maximum of {max} (BridgeConfig max_width x max_height)")]
    TooLarge {
        /// The service.
        service: String,
        /// Elements asked for.
        n: usize,
        /// Elements configured at most.
        max: usize,
    },
    /// A depth payload whose size does not match the header's width x height.
    #[error("{service}: header says {width}x{height} but {max} elements fit")]
    BadSize {
        /// The service.
        service: String,
        /// The header's width.
        width: u32,
        /// The header's height.
        height: u32,
        /// Elements that fit.
        max: usize,
    },
    /// The fill tried to write more elements than the sample holds (nothing was sent).
    #[error("{service}: the fill wrote past the sample's {capacity} elements; nothing was sent")]
    Overflow {
        /// The service.
        service: String,
        /// Elements the sample holds.
        capacity: usize,
    },
    /// The service exists with static settings other than this side's [`BridgeConfig`]: another process
    /// created it differently.
    #[error(
        "{service}: the service exists with other settings than this process's BridgeConfig ({diffs}): \
         another process created it; stop that process or use another service prefix"
    )]
    Foreign {
        /// The service.
        service: String,
        /// The settings that differ.
        diffs: String,
    },
    /// The publisher's shared memory would not fit in /dev/shm (too small, or filled by others).
    #[error(
        "{service}: needs {needed_mb:.1} MB of shared memory in {dir}, {free_mb:.1} MB free: make room there \
         (its pages are taken when first written, so a publisher that does not fit would be killed by SIGBUS \
         at a later publish) or lower the network resolution"
    )]
    SharedMemory {
        /// The service.
        service: String,
        /// The shared-memory directory (/dev/shm).
        dir: String,
        /// Megabytes the publisher needs.
        needed_mb: f64,
        /// Megabytes free there.
        free_mb: f64,
    },
    /// Another publisher holds the service's one publisher slot.
    #[error(
        "{service}: another publisher holds the service's only publisher slot ({holders}); \
         stop that process (is another abvs publishing already?) or use another service prefix"
    )]
    PublisherTaken {
        /// The service.
        service: String,
        /// The processes that hold it, as far as iceoryx2 tells.
        holders: String,
    },
}

pub mod gaze;
mod publisher;
pub mod receive_stats;
mod services;
mod subscriber;

pub use publisher::*;
pub use services::*;
pub use subscriber::*;
