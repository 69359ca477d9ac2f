//! ROS 2 messages of a published frame, CDR-encoded: the one place both the Zenoh bridge
//! (`bridges::zenoh`) and the MCAP recorder (`sinks::mcap_log`) get their bytes from.
//!
//! | topic (Zenoh key without the `/`) | type | frame_id |
//! | --- | --- | --- |
//! | `/abvs/depth` | sensor_msgs/msg/Image, `32FC1`, metres, NaN = invalid (REP 118) | `left_rect_camera` |
//! | `/abvs/camera_info` | sensor_msgs/msg/CameraInfo of that image (K, R = I, P of the rectified left camera) | `left_rect_camera` |
//! | `/abvs/points` | sensor_msgs/msg/PointCloud2, x y z float32 + rgb, valid points only | `left_home_camera` |
//! | `/tf` | tf2_msgs/msg/TFMessage: `left_home_camera` -> `left_camera`, `right_camera`, `left_rect_camera` | |
//! | `/abvs/joint_states` | sensor_msgs/msg/JointState: the six link angles (rad) at mid-exposure | `left_home_camera` |
//! | `/abvs/fovea/depth` | sensor_msgs/msg/Image, `32FC1`: the fovea's window (native scale, `tasks::fovea`) | `left_rect_camera` |
//! | `/abvs/fovea/camera_info` | sensor_msgs/msg/CameraInfo of the fovea's window (its own K and P) | `left_rect_camera` |
//! | `/abvs/fovea/points` | sensor_msgs/msg/PointCloud2 of the fovea's window | `left_home_camera` |
//! | `/abvs/confidence` | sensor_msgs/msg/Image, `32FC1`: the depth image's confidence in [0, 1] per pixel (0 = no match) | `left_rect_camera` |
//!
//! The fovea's topics exist when the run computes a fovea (on by default); the window is a crop of the main
//! map's rectified plane at the raw frames' focal length, so its frame is `left_rect_camera` too and only
//! its CameraInfo differs. A motion-gated frame's fovea is published like its main map: all NaN, no points.
//! The confidence exists when the run computes one (the default engine does): the depth image is NaN where
//! it is below `[disparity] min_confidence`, and a consumer may apply a stricter threshold of its own.
//!
//! Every header stamp is the frame's left mid-exposure time on CLOCK_MONOTONIC (`FrameHeader::t_frame_ns`
//! of the iceoryx2 services), so one frame's five messages carry one stamp. Camera frames have OpenCV axes
//! (x right, y down, z forward). The head frame is the left eye's home camera (`left_home_camera`): the
//! moving cameras are placed in it by calibrated FK every frame, the rectified left camera (the depth
//! image's) is the current left camera turned by the frame's rectifying rotation. The messages are
//! encoded by the `cdr` crate through serde (standard little-endian encapsulation, 00 01 00 00) from
//! the Humble definitions in [`SCHEMAS`]; byte arrays are written whole (`serde_bytes`).
//!
//! The large messages (the depth images, the clouds, the confidence) are built in place ([`buffers`]): the
//! output thread copies the array into a message-sized buffer at the array's place, which is fixed per
//! topic (the fields before it have a fixed length: [`image_layout`], [`cloud_layout`]), and the sink's
//! thread writes the encoded fields around it. The buffer is one the writer's pool lends (Zenoh's shared
//! memory) or the snapshot's own; either way the bytes are those of the whole message encoded at once (a
//! test checks it) and the array is copied once.
use abvs_eye::Pose;
use nalgebra::{Matrix3, Rotation3, UnitQuaternion};
use serde::Serialize;

use abvs_runtime_core::lent::Plain;
use abvs_runtime_core::messages::Published;

pub mod buffers;
pub mod type_hash;

pub use buffers::{BufferPool, Layout, MessageBuf, Payload};

/// The head frame: the left eye's camera at home, where the cloud's points are.
pub const HEAD_FRAME: &str = "left_home_camera";
/// The left eye's camera as the eye turns.
pub const LEFT_FRAME: &str = "left_camera";
/// The right eye's camera as the eye turns.
pub const RIGHT_FRAME: &str = "right_camera";
/// The rectified left camera: the depth image and its CameraInfo.
pub const RECT_FRAME: &str = "left_rect_camera";
/// JointState names: each eye's three links (`theta1..3` of docs/spec).
pub const JOINT_NAMES: [&str; 6] =
    ["left_eye_link1", "left_eye_link2", "left_eye_link3", "right_eye_link1", "right_eye_link2", "right_eye_link3"];

/// One output topic: its ROS 2 name, Zenoh key, type and ros2msg schema.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Topic {
    /// ROS 2 topic name, e.g. `/abvs/depth` (the MCAP channel).
    pub topic: &'static str,
    /// Zenoh key: the topic without its leading slash, as zenoh-bridge-ros2dds maps it.
    pub key: &'static str,
    /// ROS 2 type name, e.g. `sensor_msgs/msg/Image` (the MCAP schema name).
    pub type_name: &'static str,
    /// ros2msg schema text: the definition, then each dependency after a `MSG:` separator.
    pub schema: &'static str,
    /// The type's RIHS01 hash in Jazzy and Kilted (REP-2011; computed and checked in [`type_hash`]).
    pub rihs01: &'static str,
}

impl Topic {
    /// The type as DDS and rmw_zenoh name it: `sensor_msgs/msg/Image` -> `sensor_msgs::msg::dds_::Image_`.
    pub fn dds_type(&self) -> String {
        let (pkg, name) = self.type_name.split_once("/msg/").unwrap_or(("", self.type_name));
        format!("{pkg}::msg::dds_::{name}_")
    }
}

/// The topics, in the order [`Encoded::messages`] returns them: the main five, then the fovea's three, then
/// the confidence ([`TopicSet`]).
pub const TOPICS: [Topic; 9] = [
    Topic {
        topic: "/abvs/depth",
        key: "abvs/depth",
        type_name: "sensor_msgs/msg/Image",
        schema: SCHEMAS[0],
        rihs01: "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47",
    },
    Topic {
        topic: "/abvs/camera_info",
        key: "abvs/camera_info",
        type_name: "sensor_msgs/msg/CameraInfo",
        schema: SCHEMAS[1],
        rihs01: "RIHS01_b3dfd68ff46c9d56c80fd3bd4ed22c7a4ddce8c8348f2f59c299e73118e7e275",
    },
    Topic {
        topic: "/abvs/points",
        key: "abvs/points",
        type_name: "sensor_msgs/msg/PointCloud2",
        schema: SCHEMAS[2],
        rihs01: "RIHS01_9198cabf7da3796ae6fe19c4cb3bdd3525492988c70522628af5daa124bae2b5",
    },
    Topic {
        topic: "/tf",
        key: "tf",
        type_name: "tf2_msgs/msg/TFMessage",
        schema: SCHEMAS[3],
        rihs01: "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    },
    Topic {
        topic: "/abvs/joint_states",
        key: "abvs/joint_states",
        type_name: "sensor_msgs/msg/JointState",
        schema: SCHEMAS[4],
        rihs01: "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e",
    },
    Topic {
        topic: "/abvs/fovea/depth",
        key: "abvs/fovea/depth",
        type_name: "sensor_msgs/msg/Image",
        schema: SCHEMAS[0],
        rihs01: "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47",
    },
    Topic {
        topic: "/abvs/fovea/camera_info",
        key: "abvs/fovea/camera_info",
        type_name: "sensor_msgs/msg/CameraInfo",
        schema: SCHEMAS[1],
        rihs01: "RIHS01_b3dfd68ff46c9d56c80fd3bd4ed22c7a4ddce8c8348f2f59c299e73118e7e275",
    },
    Topic {
        topic: "/abvs/fovea/points",
        key: "abvs/fovea/points",
        type_name: "sensor_msgs/msg/PointCloud2",
        schema: SCHEMAS[2],
        rihs01: "RIHS01_9198cabf7da3796ae6fe19c4cb3bdd3525492988c70522628af5daa124bae2b5",
    },
    Topic {
        topic: "/abvs/confidence",
        key: "abvs/confidence",
        type_name: "sensor_msgs/msg/Image",
        schema: SCHEMAS[0],
        rihs01: "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47",
    },
];

/// Topics of the main map, the cameras and the joints (the first of [`TOPICS`]).
pub const MAIN_TOPICS: usize = 5;
/// Where the confidence is in [`TOPICS`].
const CONFIDENCE_TOPIC: usize = 8;

/// Which of the optional topics a run publishes: the fovea's when it computes a fovea, the confidence when it
/// computes one. The main five are always there.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TopicSet {
    /// The fovea's three topics.
    pub fovea: bool,
    /// `/abvs/confidence`.
    pub confidence: bool,
}

impl TopicSet {
    /// The topics, in [`TOPICS`] order.
    pub fn topics(self) -> Vec<&'static Topic> {
        let fovea = MAIN_TOPICS..CONFIDENCE_TOPIC;
        TOPICS
            .iter()
            .enumerate()
            .filter(|(i, _)| {
                *i < MAIN_TOPICS || (self.fovea && fovea.contains(i)) || (self.confidence && *i == CONFIDENCE_TOPIC)
            })
            .map(|(_, t)| t)
            .collect()
    }
}

/// A dependency's definition after the ros2msg separator line.
macro_rules! dep {
    ($name:literal, $text:expr) => {
        concat!(
            "================================================================================\n",
            "MSG: ",
            $name,
            "\n",
            $text
        )
    };
}

/// The ROS 2 Humble definitions (comments left out) of the five types, in [`TOPICS`] order.
pub const SCHEMAS: [&str; 5] = [
    concat!(
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\nuint8[] data\n",
        dep!("std_msgs/Header", "builtin_interfaces/Time stamp\nstring frame_id\n"),
        dep!("builtin_interfaces/Time", "int32 sec\nuint32 nanosec\n"),
    ),
    concat!(
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\nfloat64[] d\nfloat64[9] k\n",
        "float64[9] r\nfloat64[12] p\nuint32 binning_x\nuint32 binning_y\nsensor_msgs/RegionOfInterest roi\n",
        dep!("std_msgs/Header", "builtin_interfaces/Time stamp\nstring frame_id\n"),
        dep!("builtin_interfaces/Time", "int32 sec\nuint32 nanosec\n"),
        dep!("sensor_msgs/RegionOfInterest", "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n"),
    ),
    concat!(
        "std_msgs/Header header\nuint32 height\nuint32 width\nsensor_msgs/PointField[] fields\nbool is_bigendian\n",
        "uint32 point_step\nuint32 row_step\nuint8[] data\nbool is_dense\n",
        dep!("std_msgs/Header", "builtin_interfaces/Time stamp\nstring frame_id\n"),
        dep!("builtin_interfaces/Time", "int32 sec\nuint32 nanosec\n"),
        dep!(
            "sensor_msgs/PointField",
            "uint8 INT8=1\nuint8 UINT8=2\nuint8 INT16=3\nuint8 UINT16=4\nuint8 INT32=5\nuint8 UINT32=6\nuint8 FLOAT32=7\nuint8 FLOAT64=8\nstring name\nuint32 offset\nuint8 datatype\nuint32 count\n"
        ),
    ),
    concat!(
        "geometry_msgs/TransformStamped[] transforms\n",
        dep!("geometry_msgs/TransformStamped", "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform\n"),
        dep!("std_msgs/Header", "builtin_interfaces/Time stamp\nstring frame_id\n"),
        dep!("builtin_interfaces/Time", "int32 sec\nuint32 nanosec\n"),
        dep!("geometry_msgs/Transform", "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n"),
        dep!("geometry_msgs/Vector3", "float64 x\nfloat64 y\nfloat64 z\n"),
        dep!("geometry_msgs/Quaternion", "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n"),
    ),
    concat!(
        "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort\n",
        dep!("std_msgs/Header", "builtin_interfaces/Time stamp\nstring frame_id\n"),
        dep!("builtin_interfaces/Time", "int32 sec\nuint32 nanosec\n"),
    ),
];

#[derive(Serialize, Clone, Copy, Debug, PartialEq)]
struct Time {
    sec: i32,
    nanosec: u32,
}

impl Time {
    /// CLOCK_MONOTONIC ns as builtin_interfaces/Time (the nanoseconds are never negative).
    fn from_ns(t: i64) -> Time {
        Time { sec: t.div_euclid(1_000_000_000) as i32, nanosec: t.rem_euclid(1_000_000_000) as u32 }
    }
}

#[derive(Serialize)]
struct Header<'a> {
    stamp: Time,
    frame_id: &'a str,
}

#[derive(Serialize)]
struct Image<'a> {
    header: Header<'a>,
    height: u32,
    width: u32,
    encoding: &'a str,
    is_bigendian: u8,
    step: u32,
    #[serde(with = "serde_bytes")]
    data: &'a [u8],
}

#[derive(Serialize)]
struct RegionOfInterest {
    x_offset: u32,
    y_offset: u32,
    height: u32,
    width: u32,
    do_rectify: bool,
}

#[derive(Serialize)]
struct CameraInfo<'a> {
    header: Header<'a>,
    height: u32,
    width: u32,
    distortion_model: &'a str,
    d: &'a [f64],
    k: [f64; 9],
    r: [f64; 9],
    // serde implements arrays up to 32 as tuples: CDR's fixed arrays, no length
    p: [f64; 12],
    binning_x: u32,
    binning_y: u32,
    roi: RegionOfInterest,
}

#[derive(Serialize)]
struct PointField<'a> {
    name: &'a str,
    offset: u32,
    datatype: u8,
    count: u32,
}

#[derive(Serialize)]
struct PointCloud2<'a> {
    header: Header<'a>,
    height: u32,
    width: u32,
    fields: &'a [PointField<'a>],
    is_bigendian: bool,
    point_step: u32,
    row_step: u32,
    #[serde(with = "serde_bytes")]
    data: &'a [u8],
    is_dense: bool,
}

#[derive(Serialize)]
struct Vector3 {
    x: f64,
    y: f64,
    z: f64,
}

#[derive(Serialize)]
struct Quaternion {
    x: f64,
    y: f64,
    z: f64,
    w: f64,
}

#[derive(Serialize)]
struct Transform {
    translation: Vector3,
    rotation: Quaternion,
}

#[derive(Serialize)]
struct TransformStamped<'a> {
    header: Header<'a>,
    child_frame_id: &'a str,
    transform: Transform,
}

#[derive(Serialize)]
struct TfMessage<'a> {
    transforms: &'a [TransformStamped<'a>],
}

#[derive(Serialize)]
struct JointState<'a> {
    header: Header<'a>,
    name: &'a [&'a str],
    position: &'a [f64],
    velocity: &'a [f64],
    effort: &'a [f64],
}

const FLOAT32: u8 = 7;
/// Bytes of one cloud point: x, y, z float32 then rgb (PCL's packing: 0x00RRGGBB as a float32's bits).
pub const POINT_STEP: usize = 16;
const FIELDS: [PointField<'static>; 4] = [
    PointField { name: "x", offset: 0, datatype: FLOAT32, count: 1 },
    PointField { name: "y", offset: 4, datatype: FLOAT32, count: 1 },
    PointField { name: "z", offset: 8, datatype: FLOAT32, count: 1 },
    PointField { name: "rgb", offset: 12, datatype: FLOAT32, count: 1 },
];

/// A depth image and its cloud as the messages carry them, with the camera they are in: the main map's or
/// the fovea's window.
#[derive(Debug, Clone, Default)]
pub struct ImageSnapshot {
    /// Width (px).
    pub width: u32,
    /// Height (px).
    pub height: u32,
    /// fx = fy of the rectified left camera (px).
    pub f: f64,
    /// Principal point, x (px).
    pub cx: f64,
    /// Principal point, y (px).
    pub cy: f64,
    /// The Image message, its array the row-major depth (m, float32), NaN = invalid.
    pub depth: MessageBuf,
    /// The PointCloud2 message, its array [`POINT_STEP`] bytes a point.
    pub cloud: MessageBuf,
}

/// Bytes of an Image's fields before its array (the frame id is `left_rect_camera` and the encoding
/// `32FC1` for every image here, so the array's place is fixed) and of a PointCloud2's (`left_home_camera`,
/// four fields); after the array, the Image has nothing, the PointCloud2 `is_dense`.
fn heads() -> [usize; 2] {
    static HEADS: std::sync::OnceLock<[usize; 2]> = std::sync::OnceLock::new();
    *HEADS.get_or_init(|| {
        let header = |frame_id| Header { stamp: Time { sec: 0, nanosec: 0 }, frame_id };
        let mut b = Vec::new();
        let image = empty_image(header(RECT_FRAME), 0, 0);
        let _ = encode_into(&mut b, "Image", &image);
        let image = b.len();
        let _ = encode_into(&mut b, "PointCloud2", &empty_cloud(header(HEAD_FRAME), 0));
        [image, b.len() - CLOUD_TAIL]
    })
}

/// The PointCloud2's fields after its array: `is_dense`.
const CLOUD_TAIL: usize = 1;

/// Where an Image's array of `pixels` float32 goes.
pub fn image_layout(pixels: usize) -> Layout {
    Layout { head: heads()[0], array: pixels * 4, tail: 0 }
}

/// Where a PointCloud2's array of `points` goes.
pub fn cloud_layout(points: usize) -> Layout {
    Layout { head: heads()[1], array: points * POINT_STEP, tail: CLOUD_TAIL }
}

/// A 32FC1 Image in `header`'s frame without its array.
fn empty_image(header: Header<'static>, width: u32, height: u32) -> Image<'static> {
    Image { header, height, width, encoding: "32FC1", is_bigendian: 0, step: width * 4, data: &[] }
}

/// A PointCloud2 of `n` points in `header`'s frame without its array.
fn empty_cloud(header: Header<'static>, n: u32) -> PointCloud2<'static> {
    PointCloud2 {
        header,
        height: 1,
        width: n,
        fields: &FIELDS,
        is_bigendian: false,
        point_step: POINT_STEP as u32,
        row_step: n * POINT_STEP as u32,
        data: &[],
        // is_dense follows the data
        is_dense: true,
    }
}

/// `values` (float32 depths, cloud points) into `out`, which holds as many bytes as they have: their bytes
/// are the message array's (little-endian machines only: [`EncodeError::BigEndian`]).
fn copy_values<T: Plain>(out: &mut [u8], values: &[T]) {
    // SAFETY: `Plain` types have no padding and any byte is a valid u8; the slice covers exactly the values'
    // memory.
    out.copy_from_slice(unsafe {
        std::slice::from_raw_parts(values.as_ptr().cast::<u8>(), std::mem::size_of_val(values))
    });
}

impl ImageSnapshot {
    /// Copies the camera, and the depth and the cloud unless `skip` has their topics' bits (`first`: the
    /// image's first topic in [`TOPICS`]; a skipped array is not copied, nobody encodes it), each into a
    /// buffer of `pool` when it lends one. A depth map or cloud already in a buffer `lender` lent
    /// ([`abvs_runtime_core::lent::LentMap::lent_by`]) is not copied: its message waits for that buffer
    /// ([`MessageBuf::adopt`]); returns whether one does.
    fn fill(
        &mut self,
        cam: &abvs_runtime_core::messages::RectifiedCamera,
        d: &abvs_runtime_core::messages::DepthFrame,
        (pool, replaced, lender): (Option<&dyn BufferPool>, &mut u32, Option<usize>),
        (skip, first): (u32, usize),
    ) -> bool {
        (self.width, self.height) = (cam.width, cam.height);
        (self.f, self.cx, self.cy) = (cam.f, cam.cx, cam.cy);
        let mut awaits = false;
        if skip & 1 << first == 0 {
            let layout = image_layout(d.depth.len());
            if lender.is_some() && d.depth.lent_by() == lender {
                self.depth.expect_lent(layout);
                awaits = true;
            } else {
                copy_values(self.depth.array_mut(layout, pool, replaced), &d.depth);
            }
        }
        if skip & 1 << (first + 2) == 0 {
            let layout = cloud_layout(d.n_points);
            if lender.is_some() && d.cloud.lent_by() == lender {
                self.cloud.expect_lent(layout);
                awaits = true;
            } else {
                copy_values(self.cloud.array_mut(layout, pool, replaced), &d.cloud[..d.n_points]);
            }
        }
        awaits
    }

    /// Points in the cloud.
    pub fn n_points(&self) -> usize {
        self.cloud.layout().array / POINT_STEP
    }

    /// The camera's K (row-major 3x3).
    pub fn k(&self) -> [f64; 9] {
        [self.f, 0.0, self.cx, 0.0, self.f, self.cy, 0.0, 0.0, 1.0]
    }
}

/// A copy of what the messages of one frame need, taken on the pipeline's output thread
/// ([`FrameSnapshot::fill`]) and encoded later on a sink's own thread. Reused: filling a snapshot
/// allocates only when a frame has more points than any before it.
#[derive(Debug, Clone, Default)]
pub struct FrameSnapshot {
    /// Pipeline sequence number.
    pub seq: u64,
    /// The frame's instant (CLOCK_MONOTONIC ns): every message's stamp.
    pub t_frame_ns: i64,
    /// Link angles (deg), left eye then right.
    pub theta: [[f64; 3]; 2],
    /// Current left camera -> left home camera.
    pub rel_left: Pose,
    /// Current left camera -> current right camera.
    pub left_to_right: Pose,
    /// Current left camera -> rectified frame.
    pub rect_from_left: Matrix3<f64>,
    /// Stereo baseline (m).
    pub baseline_m: f64,
    /// The main depth map and cloud.
    pub main: ImageSnapshot,
    /// The fovea's, when `has_fovea`.
    pub fovea: ImageSnapshot,
    /// Whether the frame has a fovea (the run computes one).
    pub has_fovea: bool,
    /// The main map's confidence as an Image (float32, row-major, the depth image's size), when
    /// `has_confidence`.
    pub confidence: MessageBuf,
    /// Whether the frame has a confidence (the run computes one).
    pub has_confidence: bool,
    /// Topics not to encode (bit i: [`TOPICS`]`[i]`): nobody receives them; their arrays are not copied.
    pub skip: u32,
    /// The main depth image's or cloud's array is in a buffer lent to the frame's depth map or cloud, not
    /// copied: the message is complete once that buffer comes ([`FrameSnapshot::adopt`]).
    pub awaits_depth: bool,
}

impl FrameSnapshot {
    /// Copies a published frame's depth, cloud and geometry (and its fovea's), leaving out the arrays of
    /// the topics in `skip` ([`FrameSnapshot::skip`]), each into a buffer of the writer's `pool` when it
    /// lends one ([`buffers`]). Returns the arrays that a writer still held from an earlier frame, so that
    /// new ones were allocated (none when writers let go). The main depth map, when it is in a buffer
    /// `lender` lent, and the cloud likewise, is not copied: see [`FrameSnapshot::awaits_depth`].
    pub fn fill(&mut self, out: &Published, skip: u32, pool: Option<&dyn BufferPool>, lender: Option<usize>) -> u32 {
        self.skip = skip;
        self.seq = out.seq;
        self.t_frame_ns = out.t_frame_ns;
        self.theta = *out.theta;
        self.rel_left = out.pose.rel_left;
        self.left_to_right = out.pose.left_to_right;
        self.rect_from_left = out.rect.rect_from_left;
        self.baseline_m = out.rect.baseline_m;
        let mut replaced = 0;
        self.awaits_depth = self.main.fill(out.cam, out.depth, (pool, &mut replaced, lender), (skip, 0));
        self.has_fovea = out.fovea.is_some();
        if let Some(f) = out.fovea {
            self.fovea.fill(&f.cam, &f.depth, (pool, &mut replaced, None), (skip, MAIN_TOPICS));
        }
        self.has_confidence = out.confidence.is_some();
        if let Some(c) = out.confidence.filter(|_| skip & 1 << CONFIDENCE_TOPIC == 0) {
            copy_values(self.confidence.array_mut(image_layout(c.len()), pool, &mut replaced), c);
        }
        replaced
    }

    /// Completes the main depth image or cloud with the buffer its array was written in (lent for it by
    /// this output and taken back from the frame: `cloud` says which), ending the wait when no other message
    /// waits ([`FrameSnapshot::awaits_depth`]); a buffer the message does not wait for, or too short, is
    /// returned.
    pub fn adopt(&mut self, buf: Box<dyn buffers::LentBuf>, cloud: bool) -> Result<(), Box<dyn buffers::LentBuf>> {
        let m = if cloud { &mut self.main.cloud } else { &mut self.main.depth };
        if !m.expecting() {
            return Err(buf);
        }
        m.adopt(buf)?;
        self.awaits_depth = self.main.depth.expecting() || self.main.cloud.expecting();
        Ok(())
    }

    /// The buffer of topic `i`'s message ([`TOPICS`]) when it is a large one.
    fn large_mut(&mut self, i: usize) -> Option<&mut MessageBuf> {
        match i {
            0 => Some(&mut self.main.depth),
            2 => Some(&mut self.main.cloud),
            5 => Some(&mut self.fovea.depth),
            7 => Some(&mut self.fovea.cloud),
            CONFIDENCE_TOPIC => Some(&mut self.confidence),
            _ => None,
        }
    }

    /// Gives the buffers lent for this frame and not sent (a frame that failed) back to the writer's pool.
    pub fn release(&mut self) {
        for i in 0..TOPICS.len() {
            if let Some(b) = self.large_mut(i) {
                b.release();
            }
        }
    }

    /// Where each camera frame is in the head frame (`left_home_camera`): (child frame, pose that maps the
    /// child's coordinates to the head's), as `/tf` carries them.
    pub fn transforms(&self) -> [(&'static str, Pose); 3] {
        let right = self.rel_left.compose(&self.left_to_right.inverse());
        let rect = self.rel_left.compose(&Pose::new(self.rect_from_left.transpose(), nalgebra::Vector3::zeros()));
        [(LEFT_FRAME, self.rel_left), (RIGHT_FRAME, right), (RECT_FRAME, rect)]
    }
}

/// One encoded message: a small one's bytes, or a large one's fields around its array (written into the
/// snapshot's buffer of it).
#[derive(Debug, Default)]
struct Message {
    bytes: Vec<u8>,
    /// The message is in the snapshot's [`MessageBuf`].
    large: bool,
    /// Not encoded for the last frame (its topic in [`FrameSnapshot::skip`]).
    skipped: bool,
}

/// The encoded messages of one frame, buffers reused from frame to frame.
#[derive(Debug, Default)]
pub struct Encoded {
    msgs: [Message; 9],
    /// The topics encoded for the last frame (indices into [`TOPICS`] and `msgs` alike).
    encoded: Vec<usize>,
}

fn quaternion(r: &Matrix3<f64>) -> Quaternion {
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(r));
    Quaternion { x: q.i, y: q.j, z: q.k, w: q.w }
}

/// Why a frame's messages could not be encoded.
#[derive(Debug, thiserror::Error)]
pub enum EncodeError {
    /// A message that serde's CDR encoder refused.
    #[error("{type_name}: CDR encoding: {source}")]
    Cdr {
        /// The message type.
        type_name: &'static str,
        /// What the encoder said.
        #[source]
        source: cdr::Error,
    },
    /// An array longer than CDR's 32-bit length.
    #[error("{type_name}: {bytes} bytes is more than a CDR sequence holds")]
    TooLarge {
        /// The message type.
        type_name: &'static str,
        /// The array's length.
        bytes: usize,
    },
    /// An image whose array does not hold width x height values.
    #[error("{topic}: {len} values for a {width}x{height} image")]
    Shape {
        /// The topic.
        topic: &'static str,
        /// Values in the array.
        len: usize,
        /// The image's width.
        width: u32,
        /// Its height.
        height: u32,
    },
    /// Fields that do not take the bytes the array's place was computed with (never: their length is
    /// fixed per topic, [`image_layout`], [`cloud_layout`]).
    #[error("{type_name}: {bytes} bytes of fields where the buffer has {room}")]
    Layout {
        /// The message type.
        type_name: &'static str,
        /// Bytes the fields took.
        bytes: usize,
        /// Bytes the buffer has for them.
        room: usize,
    },
    /// A big-endian machine (the messages are written little-endian, as ROS 2 sends them on x86 and ARM).
    #[error("ROS 2 messages are built for little-endian machines only")]
    BigEndian,
}

fn encode_into<T: Serialize>(buf: &mut Vec<u8>, type_name: &'static str, msg: &T) -> Result<(), EncodeError> {
    buf.clear();
    cdr::serialize_into::<_, _, _, cdr::CdrLe>(&mut *buf, msg, cdr::Infinite)
        .map_err(|source| EncodeError::Cdr { type_name, source })
}

impl Message {
    /// The fields of `msg`, whose byte array (left empty in `msg`) is in `buf`, written around it: the
    /// message encoded with an empty array ends with the array's length (a u32 aligned by what precedes
    /// it, whatever the array holds) and the fields after it, whose alignment is 1, so the length is
    /// patched in.
    fn split<T: Serialize>(
        &mut self,
        type_name: &'static str,
        msg: &T,
        buf: &mut MessageBuf,
    ) -> Result<(), EncodeError> {
        encode_into(&mut self.bytes, type_name, msg)?;
        let Layout { head, array, tail } = buf.layout();
        if self.bytes.len() != head + tail {
            return Err(EncodeError::Layout { type_name, bytes: self.bytes.len(), room: head + tail });
        }
        let n = u32::try_from(array).map_err(|_| EncodeError::TooLarge { type_name, bytes: array })?;
        self.bytes[head - 4..head].copy_from_slice(&n.to_le_bytes());
        let (h, t) = buf.fields_mut();
        h.copy_from_slice(&self.bytes[..head]);
        t.copy_from_slice(&self.bytes[head..]);
        self.large = true;
        Ok(())
    }

    fn whole<T: Serialize>(&mut self, type_name: &'static str, msg: &T) -> Result<(), EncodeError> {
        self.large = false;
        encode_into(&mut self.bytes, type_name, msg)
    }
}

/// The Image, CameraInfo and PointCloud2 of `img` into `msgs`, with the topics' `types`; those whose bit
/// is in `skip` (from `first`, the Image's topic) are marked skipped.
fn encode_image(
    msgs: &mut [Message],
    types: [&'static str; 3],
    img: &mut ImageSnapshot,
    header: impl Fn(&'static str) -> Header<'static>,
    (skip, first): (u32, usize),
) -> Result<(), EncodeError> {
    let [depth, info, points] = msgs else { return Ok(()) };
    for (i, m) in [&mut *depth, &mut *info, &mut *points].into_iter().enumerate() {
        m.skipped = skip & 1 << (first + i) != 0;
    }
    if !depth.skipped {
        depth.split(types[0], &empty_image(header(RECT_FRAME), img.width, img.height), &mut img.depth)?;
    }
    if !info.skipped {
        info.whole(
            types[1],
            &CameraInfo {
                header: header(RECT_FRAME),
                height: img.height,
                width: img.width,
                // the image is rectified: no distortion left
                distortion_model: "plumb_bob",
                d: &[0.0; 5],
                k: img.k(),
                r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                p: [img.f, 0.0, img.cx, 0.0, 0.0, img.f, img.cy, 0.0, 0.0, 0.0, 1.0, 0.0],
                binning_x: 0,
                binning_y: 0,
                roi: RegionOfInterest { x_offset: 0, y_offset: 0, height: 0, width: 0, do_rectify: false },
            },
        )?;
    }
    if points.skipped {
        return Ok(());
    }
    let cloud = empty_cloud(header(HEAD_FRAME), img.n_points() as u32);
    points.split(types[2], &cloud, &mut img.cloud)
}

impl Encoded {
    /// Encodes the messages of `s` (CDR, little-endian encapsulation): the main five, then the fovea's three
    /// when it has one, then the confidence when it has one. The large messages' fields are written around
    /// their arrays, in the snapshot's buffers.
    pub fn encode(&mut self, s: &mut FrameSnapshot) -> Result<(), EncodeError> {
        if cfg!(target_endian = "big") {
            return Err(EncodeError::BigEndian);
        }
        let stamp = Time::from_ns(s.t_frame_ns);
        let header = |frame_id| Header { stamp, frame_id };
        let types = |i: usize| [TOPICS[i].type_name, TOPICS[i + 1].type_name, TOPICS[i + 2].type_name];
        self.encoded.clear();
        let (main, rest) = self.msgs.split_at_mut(3);
        encode_image(main, types(0), &mut s.main, header, (s.skip, 0))?;
        let tfs = s.transforms().map(|(child, p)| TransformStamped {
            header: header(HEAD_FRAME),
            child_frame_id: child,
            transform: Transform { translation: Vector3 { x: p.t.x, y: p.t.y, z: p.t.z }, rotation: quaternion(&p.r) },
        });
        (rest[0].skipped, rest[1].skipped) = (s.skip & 1 << 3 != 0, s.skip & 1 << 4 != 0);
        if !rest[0].skipped {
            rest[0].whole(TOPICS[3].type_name, &TfMessage { transforms: &tfs })?;
        }
        let t = &s.theta;
        let position = [t[0][0], t[0][1], t[0][2], t[1][0], t[1][1], t[1][2]].map(f64::to_radians);
        if !rest[1].skipped {
            rest[1].whole(
                TOPICS[4].type_name,
                &JointState {
                    header: header(HEAD_FRAME),
                    name: &JOINT_NAMES,
                    position: &position,
                    velocity: &[],
                    effort: &[],
                },
            )?;
        }
        self.encoded.extend(0..MAIN_TOPICS);
        if s.has_fovea {
            encode_image(&mut rest[2..5], types(MAIN_TOPICS), &mut s.fovea, header, (s.skip, MAIN_TOPICS))?;
            self.encoded.extend(MAIN_TOPICS..CONFIDENCE_TOPIC);
        }
        if s.has_confidence {
            let m = &mut rest[5];
            m.skipped = s.skip & 1 << CONFIDENCE_TOPIC != 0;
            if !m.skipped {
                let (width, height) = (s.main.width, s.main.height);
                let len = s.confidence.layout().array / 4;
                if len != width as usize * height as usize {
                    let topic = TOPICS[CONFIDENCE_TOPIC].topic;
                    return Err(EncodeError::Shape { topic, len, width, height });
                }
                let image = empty_image(header(RECT_FRAME), width, height);
                m.split(TOPICS[CONFIDENCE_TOPIC].type_name, &image, &mut s.confidence)?;
            }
            self.encoded.push(CONFIDENCE_TOPIC);
        }
        Ok(())
    }

    /// (topic, CDR bytes) of the last encoded frame `s`, in [`TOPICS`] order, without the skipped topics:
    /// a large message is handed over in its buffer (lent by the writer's pool or shared with the snapshot).
    pub fn messages<'a, 's>(
        &'a self,
        s: &'s mut FrameSnapshot,
    ) -> impl Iterator<Item = (&'static Topic, Payload<'a>)> + use<'a, 's> {
        self.encoded.iter().filter(|&&i| !self.msgs[i].skipped).map(move |&i| {
            let m = &self.msgs[i];
            let p = match s.large_mut(i).filter(|_| m.large) {
                Some(b) => b.payload(),
                None => Payload::Small(&m.bytes),
            };
            (&TOPICS[i], p)
        })
    }

    /// The topics of the last frame that were skipped (not encoded: [`FrameSnapshot::skip`]).
    pub fn skipped(&self) -> impl Iterator<Item = &'static Topic> + '_ {
        self.encoded.iter().filter(|&&i| self.msgs[i].skipped).map(|&i| &TOPICS[i])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use abvs_runtime_core::messages::CloudPoint;

    #[test]
    fn time_and_header_bytes() {
        assert_eq!(Time::from_ns(1_500_000_000), Time { sec: 1, nanosec: 500_000_000 });
        assert_eq!(Time::from_ns(-1), Time { sec: -1, nanosec: 999_999_999 });
        let mut b = Vec::new();
        encode_into(&mut b, "std_msgs/msg/Header", &Header { stamp: Time { sec: 2, nanosec: 3 }, frame_id: "ab" })
            .unwrap();
        // encapsulation, sec, nanosec, string length (with NUL), "ab\0"
        assert_eq!(b, [0, 1, 0, 0, 2, 0, 0, 0, 3, 0, 0, 0, 3, 0, 0, 0, b'a', b'b', 0]);
    }

    /// An image of `w` x `h` with `points`, its arrays in buffers of `pool` while it lends them.
    fn image_in(w: u32, h: u32, f: f64, points: &[[f32; 3]], pool: Option<&dyn BufferPool>) -> ImageSnapshot {
        let depth: Vec<f32> = (0..w * h).map(|i| if i % 3 == 0 { f32::NAN } else { i as f32 * 0.25 }).collect();
        let pts: Vec<CloudPoint> = points.iter().map(|p| CloudPoint::new(glam::Vec3::from_array(*p), 9)).collect();
        let mut img = ImageSnapshot { width: w, height: h, f, cx: 0.5, cy: 0.0, ..Default::default() };
        let mut replaced = 0;
        copy_values(img.depth.array_mut(image_layout(depth.len()), pool, &mut replaced), &depth);
        copy_values(img.cloud.array_mut(cloud_layout(pts.len()), pool, &mut replaced), &pts);
        img
    }

    fn image(w: u32, h: u32, f: f64, points: &[[f32; 3]]) -> ImageSnapshot {
        image_in(w, h, f, points, None)
    }

    fn confidence(values: &[f32], pool: Option<&dyn BufferPool>) -> MessageBuf {
        let mut b = MessageBuf::default();
        copy_values(b.array_mut(image_layout(values.len()), pool, &mut 0), values);
        b
    }

    /// The Image and PointCloud2 of `img` encoded whole, as serde writes them with their arrays.
    fn whole(img: &ImageSnapshot, stamp: Time) -> [Vec<u8>; 2] {
        let (mut a, mut b) = (Vec::new(), Vec::new());
        let header = |frame_id| Header { stamp, frame_id };
        let image = Image { data: img.depth.array(), ..empty_image(header(RECT_FRAME), img.width, img.height) };
        encode_into(&mut a, "Image", &image).unwrap();
        let pc = PointCloud2 { data: img.cloud.array(), ..empty_cloud(header(HEAD_FRAME), img.n_points() as u32) };
        encode_into(&mut b, "PointCloud2", &pc).unwrap();
        [a, b]
    }

    #[test]
    fn buffers_hold_the_whole_message() {
        // any array length, any stamp, in a lent buffer or the snapshot's own: the fields written around
        // the array make the message serde encodes at once
        let mut e = Encoded::default();
        for (k, (w, h, np)) in [(2, 1, 1), (3, 3, 0), (5, 2, 3), (1, 1, 7), (4, 2, 5)].into_iter().enumerate() {
            // none, then a pool that runs out partway through the frame, then one that lends every buffer
            let pool = buffers::tests::VecPool { left: (k * 2).into() };
            let pool = (k > 0).then_some(&pool as &dyn BufferPool);
            let pts: Vec<[f32; 3]> = (0..np).map(|i| [i as f32, -1.5, 2.0]).collect();
            let conf: Vec<f32> = (0..w * h).map(|i| i as f32 / 7.0).collect();
            let mut s = FrameSnapshot {
                t_frame_ns: 1_234_567_891 * k as i64 - 7,
                rect_from_left: Matrix3::identity(),
                main: image_in(w, h, 100.0, &pts, pool),
                fovea: image_in(h + 1, w, 250.0, &pts[..np / 2], pool),
                has_fovea: k % 2 == 0,
                confidence: confidence(&conf, pool),
                has_confidence: k != 1,
                ..Default::default()
            };
            let stamp = Time::from_ns(s.t_frame_ns);
            let expected = [whole(&s.main, stamp), whole(&s.fovea, stamp)];
            // the confidence is the main depth image's Image with the confidence's array
            let c = ImageSnapshot { depth: s.confidence.clone(), ..s.main.clone() };
            let expected_conf = whole(&c, stamp)[0].clone();
            e.encode(&mut s).unwrap();
            let m: Vec<_> = e.messages(&mut s).collect();
            assert_eq!(m.len(), MAIN_TOPICS + 3 * s.has_fovea as usize + s.has_confidence as usize);
            if s.has_confidence {
                let (topic, msg) = m.last().unwrap();
                assert_eq!(topic.topic, "/abvs/confidence");
                assert_eq!(msg.bytes(), &expected_conf[..], "{k}");
            }
            let lent = m.iter().filter(|(_, p)| matches!(p, Payload::Lent(..))).count();
            let images = &m[..MAIN_TOPICS + 3 * s.has_fovea as usize];
            for (first, [depth, cloud]) in [0, MAIN_TOPICS].into_iter().zip(&expected).take(images.len() / 4) {
                assert_eq!(images[first].1.bytes(), &depth[..], "{k} {}", images[first].0.topic);
                assert_eq!(images[first + 2].1.bytes(), &cloud[..], "{k} {}", images[first + 2].0.topic);
                assert!(matches!(images[first + 1].1, Payload::Small(_)));
            }
            // the pool's buffers went to the writer, as many as it lent for the topics sent
            assert_eq!(lent > 0, k > 0, "{k}");
            drop(m);
            // the writer let go: the snapshot's own buffers are its own again
            s.release();
            let mut replaced = 0;
            s.main.cloud.array_mut(cloud_layout(1), None, &mut replaced);
            s.confidence.array_mut(image_layout(1), None, &mut replaced);
            assert_eq!(replaced, 0);
        }
    }

    #[test]
    fn a_cloud_point_is_its_pointcloud2_record() {
        // x, y, z, rgb (FIELDS' offsets), little-endian, gray as 0xffGGGGGG
        let p = CloudPoint::new(glam::Vec3::new(1.0, -0.5, 1e-3), 0x5a);
        let mut b = [0u8; POINT_STEP + 3];
        copy_values(&mut b[3..], &[p]);
        let expected: Vec<u8> = [1f32.to_bits(), (-0.5f32).to_bits(), 1e-3f32.to_bits(), 0xff5a_5a5a]
            .iter()
            .flat_map(|w| w.to_le_bytes())
            .collect();
        assert_eq!(&b[3..], &expected[..]);
        assert_eq!((FIELDS[3].offset as usize, std::mem::size_of::<CloudPoint>()), (12, POINT_STEP));
        assert_eq!((p.gray(), p.pos()), (0x5a, glam::Vec3::new(1.0, -0.5, 1e-3)));
    }

    #[test]
    fn skipped_topics_are_not_encoded() {
        let mut s = FrameSnapshot {
            main: image(2, 1, 100.0, &[[1.0, 2.0, 3.0]]),
            fovea: image(1, 1, 200.0, &[]),
            has_fovea: true,
            rect_from_left: Matrix3::identity(),
            skip: 1 << 2 | 1 << 3 | 1 << 5,
            ..Default::default()
        };
        let mut e = Encoded::default();
        e.encode(&mut s).unwrap();
        let names = |it: &mut dyn Iterator<Item = &'static Topic>| it.map(|t| t.topic).collect::<Vec<_>>();
        let written = names(&mut e.messages(&mut s).map(|(t, _)| t));
        assert_eq!(
            written,
            ["/abvs/depth", "/abvs/camera_info", "/abvs/joint_states", "/abvs/fovea/camera_info", "/abvs/fovea/points"]
        );
        assert_eq!(names(&mut e.skipped()), ["/abvs/points", "/tf", "/abvs/fovea/depth"]);
        // the skip lasts one frame: the next encodes every topic again
        s.skip = 0;
        e.encode(&mut s).unwrap();
        assert_eq!((e.messages(&mut s).count(), e.skipped().count()), (8, 0));
    }

    #[test]
    fn snapshot_encodes_every_topic() {
        let mut s = FrameSnapshot {
            main: image(2, 1, 100.0, &[[1.0, 2.0, 3.0]]),
            rect_from_left: Matrix3::identity(),
            ..Default::default()
        };
        let mut e = Encoded::default();
        e.encode(&mut s).unwrap();
        let m: Vec<_> = e.messages(&mut s).collect();
        assert_eq!(m.len(), 5);
        // the cloud's data ends the message, followed by is_dense
        let pc = m[2].1.bytes();
        let point: Vec<u8> =
            [1f32, 2.0, 3.0].iter().flat_map(|v| v.to_le_bytes()).chain(0xff09_0909u32.to_le_bytes()).collect();
        assert_eq!(&pc[pc.len() - 17..pc.len() - 1], &point[..]);
        assert_eq!(pc[pc.len() - 1], 1);
        // the fovea's CameraInfo carries its own K
        s.fovea = image(4, 3, 480.0, &[]);
        s.has_fovea = true;
        // a confidence of another size than the depth image's is refused
        s.has_confidence = true;
        assert!(matches!(e.encode(&mut s), Err(EncodeError::Shape { len: 0, width: 2, height: 1, .. })));
        s.confidence = confidence(&[0.5; 2], None);
        e.encode(&mut s).unwrap();
        let m: Vec<_> = e.messages(&mut s).collect();
        assert_eq!(m.iter().map(|(t, _)| t.topic).collect::<Vec<_>>(), TOPICS.map(|t| t.topic));
        let info = m[6].1.bytes();
        let k0 = 480f64.to_le_bytes();
        assert!(info.windows(8).any(|w| w == k0) && !m[1].1.bytes().windows(8).any(|w| w == k0));
        for t in TOPICS {
            assert!(t.schema.starts_with(|c: char| c.is_ascii_lowercase()), "{}", t.type_name);
            assert_eq!(t.key, &t.topic[1..]);
            assert!(t.dds_type().contains("::msg::dds_::") && t.dds_type().ends_with('_'), "{}", t.dds_type());
        }
        let set = |fovea, confidence| TopicSet { fovea, confidence }.topics();
        assert_eq!(set(false, false).len(), MAIN_TOPICS);
        assert_eq!(set(true, true), TOPICS.iter().collect::<Vec<_>>());
        assert_eq!(set(false, true).last().map(|t| t.topic), Some("/abvs/confidence"));
        assert_eq!(set(true, false).len(), CONFIDENCE_TOPIC);
    }
}
