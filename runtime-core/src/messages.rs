//! The messages between the runtime's roles, and the one clock: every source, stage, sink and bridge imports
//! its data types from here (none from another role's module), so dependencies run one way.
//!
//! ```text
//! source ─ SourcePair + EncoderSample ─> align ─ theta ─> kinematics ─ StereoPose ─> rectify ─ RectifiedPair ─>
//!   disparity ─ disparity map (+ confidence) ─> depth ─ DepthFrame ─> Published (sinks, bridges)
//! ```
//! A frame travels through the stages in one pooled [`Work`] holding every message of that frame.
use glam::Vec3;
use nalgebra::{Matrix3, Vector3};

use abvs_eye::Pose;

use crate::lent::{F32Map, LentMap, Plain};

// ---------------------------------------------------------------- clock

/// CLOCK_MONOTONIC in nanoseconds (the clock of `t_frame_ns` and `t_publish_ns`).
// (time_t and c_long are 32-bit on 32-bit targets: the casts are not no-ops everywhere)
#[allow(clippy::unnecessary_cast)]
pub fn monotonic_ns() -> i64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: clock_gettime writes into the timespec we own; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as i64 * 1_000_000_000 + ts.tv_nsec as i64
}

// ---------------------------------------------------------------- sources

/// One grayscale camera frame as it leaves a source: 8-bit luma, row-major, tightly packed.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// Source sequence number (V4L2 buffer sequence, or the recorded index).
    pub seq: u64,
    /// Start of exposure, CLOCK_MONOTONIC, nanoseconds.
    pub t_start_ns: i64,
    /// Exposure time, nanoseconds (mid-exposure = t_start_ns + exposure_ns / 2).
    pub exposure_ns: i64,
    /// Where the stamp fixes the readout ([`SourcePair::readout_anchor`]; 0: at the first row).
    pub readout_anchor: f64,
    /// Frame width (px).
    pub width: u32,
    /// Frame height (px).
    pub height: u32,
    /// 8-bit gray pixels, row-major, `width * height`.
    pub gray: Vec<u8>,
}

impl Frame {
    /// Mid-exposure time (CLOCK_MONOTONIC ns): the instant the encoders are interpolated to.
    pub fn t_mid_ns(&self) -> i64 {
        self.t_start_ns + self.exposure_ns / 2
    }
}

/// A left/right pair of frames taken together.
#[derive(Clone, Debug, PartialEq)]
pub struct FramePair {
    /// Pair sequence number (increases by one per pair delivered).
    pub seq: u64,
    /// The left eye's frame.
    pub left: Frame,
    /// The right eye's frame.
    pub right: Frame,
}

/// One pair as a source hands it to the graph (borrowed from the source until its next pair; the runner
/// copies it into a pooled [`Work`]).
pub struct SourcePair<'a> {
    /// The frame's `seq` in its session (before looping; for a live camera its frame number): the key of
    /// its ground truth.
    pub session_seq: u64,
    /// Pipeline sequence number (keeps increasing when a replay loops).
    pub seq: u64,
    /// Start of exposure of the left frame's first row (conventions.md "Time").
    pub t_start_ns: i64,
    /// The right frame's start of exposure (live pairs differ by up to the pairing tolerance).
    pub right_t_start_ns: i64,
    /// Exposure time of the left frame (ns).
    pub exposure_ns: i64,
    /// Rolling-shutter readout: first row's start of exposure to the last row's (0 = global shutter).
    pub readout_ns: i64,
    /// The row (fraction of the image, 0 = top) whose start of exposure the stamps give independently of
    /// the readout: 0 when frames are stamped at their first row (sessions, start-of-exposure drivers), 1
    /// when at the end of the frame (the start is then the stamp minus exposure and readout). A readout
    /// error moves row `r`'s assumed time by `readout error x (r - anchor)`.
    pub readout_anchor: f64,
    /// The left frame's gray pixels (the source's size).
    pub left: &'a [u8],
    /// The right frame's gray pixels.
    pub right: &'a [u8],
}

// ---------------------------------------------------------------- encoders, poses

/// One encoder reading of the three links (deg, homed) at a CLOCK_MONOTONIC time (s).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EncoderSample {
    /// CLOCK_MONOTONIC time (s).
    pub t_s: f64,
    /// The three links' angles (deg).
    pub theta_deg: [f64; 3],
}

/// Both eyes' poses at one instant and the extrinsic between the current cameras (metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StereoPose {
    /// T_rel,l: current left camera -> left home camera.
    pub rel_left: Pose,
    /// T_rel,r: current right camera -> right home camera.
    pub rel_right: Pose,
    /// T_l^r: current left camera -> current right camera.
    pub left_to_right: Pose,
}

/// Most row bands a frame's per-row correction uses (the pooled frames hold this many nodes).
pub const MAX_ROW_BANDS: usize = 64;

/// One frame's motion during its exposure: what the align and kinematics stages learn from the encoders
/// about the rows' instants (conventions.md "Time"). Buffers are sized at start-up; stages refill them.
#[derive(Debug, Clone)]
pub struct FrameMotion {
    /// Start of exposure of row 0, left and right (CLOCK_MONOTONIC ns).
    pub t_start_ns: [i64; 2],
    /// Exposure time (ns).
    pub exposure_ns: i64,
    /// First row's start of exposure to the last row's (ns); 0 = global shutter.
    pub readout_ns: i64,
    /// Link angles (deg) of each eye at its frame instant -/+ `tasks::motion::SPEED_DT_S`.
    pub theta_pm: [[[f64; 3]; 2]; 2],
    /// Link angles (deg) of each eye at its frame instant -/+ `tasks::motion::WIDE_DT_S`.
    pub theta_wide: [[[f64; 3]; 2]; 2],
    /// Per-row correction: link angles at the row-band nodes (node b at row b (H - 1) / bands, that row's
    /// mid-exposure), per eye; empty when the frame is corrected as a whole (global shutter, or off).
    pub band_theta: [Vec<[f64; 3]>; 2],
    /// Per node: the rotation from the virtual camera (the eye at the frame instant) to the camera as it
    /// was when that row exposed, `R_row^T R_frame` (kinematics stage).
    pub band_rot: [Vec<Matrix3<f64>>; 2],
    /// Angular speed of each camera at its frame instant (deg/s).
    pub speed_deg_s: [f64; 2],
    /// Angular velocity of each camera at its frame instant, in that camera's own (current) frame (rad/s):
    /// `R(t + dt) = R(t) exp([omega dt]x)` for its pose `R` (current camera -> home camera).
    pub omega_rad_s: [Vector3<f64>; 2],
    /// Each camera's mean angular velocity over the `WIDE_DT_S` before and after its frame instant, in its
    /// frame at that instant (rad/s): the two differ when the eye accelerated while the rows exposed.
    pub omega_wide_rad_s: [[Vector3<f64>; 2]; 2],
    /// Velocity of each camera's optical centre at its frame instant, in that camera's frame (m/s): the camera
    /// sits off the mechanism's centre, so it translates while the eye turns.
    pub vel_m_s: [Vector3<f64>; 2],
    /// [`SourcePair::readout_anchor`] of the frame.
    pub readout_anchor: f64,
    /// Motion blur of the faster eye over the exposure, in rectified output pixels at the image centre.
    pub blur_px: f64,
    /// Blur above the run's threshold, or the exposure overlaps a commanded saccade (`gaze.gated_saccade`):
    /// depth is published invalid (NaN) with an empty cloud.
    pub gated: bool,
    /// The gaze at this frame (the gaze stage's; idle without one).
    pub gaze: crate::gaze::GazeState,
}

impl Default for FrameMotion {
    fn default() -> Self {
        FrameMotion::new()
    }
}

impl FrameMotion {
    /// Empty buffers sized for [`MAX_ROW_BANDS`].
    pub fn new() -> Self {
        let angles = || Vec::with_capacity(MAX_ROW_BANDS + 1);
        let rots = || Vec::with_capacity(MAX_ROW_BANDS + 1);
        FrameMotion {
            t_start_ns: [0; 2],
            exposure_ns: 0,
            readout_ns: 0,
            theta_pm: [[[0.0; 3]; 2]; 2],
            band_theta: [angles(), angles()],
            band_rot: [rots(), rots()],
            speed_deg_s: [0.0; 2],
            omega_rad_s: [Vector3::zeros(); 2],
            theta_wide: [[[0.0; 3]; 2]; 2],
            omega_wide_rad_s: [[Vector3::zeros(); 2]; 2],
            vel_m_s: [Vector3::zeros(); 2],
            readout_anchor: 0.0,
            blur_px: 0.0,
            gated: false,
            gaze: crate::gaze::GazeState::default(),
        }
    }

    /// Copies `other` into this frame's buffers (no allocation once they have grown to its size).
    pub fn copy_from(&mut self, other: &FrameMotion) {
        (self.t_start_ns, self.exposure_ns, self.readout_ns) = (other.t_start_ns, other.exposure_ns, other.readout_ns);
        (self.theta_pm, self.speed_deg_s, self.blur_px, self.gated, self.gaze) =
            (other.theta_pm, other.speed_deg_s, other.blur_px, other.gated, other.gaze);
        (self.omega_rad_s, self.readout_anchor) = (other.omega_rad_s, other.readout_anchor);
        (self.theta_wide, self.omega_wide_rad_s, self.vel_m_s) =
            (other.theta_wide, other.omega_wide_rad_s, other.vel_m_s);
        for eye in 0..2 {
            self.band_theta[eye].clear();
            self.band_theta[eye].extend_from_slice(&other.band_theta[eye]);
            self.band_rot[eye].clear();
            self.band_rot[eye].extend_from_slice(&other.band_rot[eye]);
        }
    }

    /// The faster eye's angular speed at the frame instant (deg/s).
    pub fn max_speed_deg_s(&self) -> f64 {
        self.speed_deg_s[0].max(self.speed_deg_s[1])
    }
}

// ---------------------------------------------------------------- rectified pair

/// The rectified output: a pinhole camera shared by both eyes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RectifiedCamera {
    /// Width (px).
    pub width: u32,
    /// Height (px).
    pub height: u32,
    /// Focal length (px), both axes.
    pub f: f64,
    /// Principal point, x (px).
    pub cx: f64,
    /// Principal point, y (px).
    pub cy: f64,
}

impl RectifiedCamera {
    /// A rectified camera at `width` x `height` whose horizontal field of view is `hfov_deg`.
    pub fn with_hfov(width: u32, height: u32, hfov_deg: f64) -> Self {
        let f = (width as f64 / 2.0) / (hfov_deg.to_radians() / 2.0).tan();
        RectifiedCamera { width, height, f, cx: (width as f64 - 1.0) / 2.0, cy: (height as f64 - 1.0) / 2.0 }
    }
}

/// Rectifying rotations for one extrinsic.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rectification {
    /// Current left camera -> rectified frame.
    pub rect_from_left: Matrix3<f64>,
    /// Current right camera -> rectified frame (same orientation, origin at the right camera).
    pub rect_from_right: Matrix3<f64>,
    /// Distance between the optical centres (m).
    pub baseline_m: f64,
}

/// A rectified pair at the output resolution and the rotations that made it.
pub struct RectifiedPair {
    /// Rectified left image (gray, row-major).
    pub left: Vec<u8>,
    /// Rectified right image.
    pub right: Vec<u8>,
    /// 1 where the rectified left pixel sees the raw image.
    pub valid: Vec<u8>,
    /// The rotations that made the pair (`None` before the rectify stage ran).
    pub rect: Option<Rectification>,
}

impl RectifiedPair {
    /// A pair of `width` x `height` buffers.
    pub fn new(width: u32, height: u32) -> Self {
        let n = (width * height) as usize;
        RectifiedPair { left: vec![0; n], right: vec![0; n], valid: vec![0; n], rect: None }
    }
}

// ---------------------------------------------------------------- depth

/// One point of a frame's cloud: metres in the left home camera frame and the pixel's gray level. Its 16
/// bytes are those of a point of the ROS 2 PointCloud2 (fields x, y, z, rgb) and of the iceoryx2 cloud
/// (x, y, z, rgba): each output sends the depth stage's array as it is.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[repr(C)]
pub struct CloudPoint {
    /// X (m, right).
    pub x: f32,
    /// Y (m, down).
    pub y: f32,
    /// Z (m, forward).
    pub z: f32,
    /// The gray level as packed rgb with an opaque alpha: 0xffGGGGGG (PCL's 0x00RRGGBB, whose top byte
    /// rviz ignores; iceoryx2's 0xAABBGGRR).
    pub rgb: u32,
}

// SAFETY: four 4-byte numbers, repr(C): no padding, any bits valid.
unsafe impl Plain for CloudPoint {}

impl CloudPoint {
    /// The point at `p` of gray level `g`.
    #[inline]
    pub fn new(p: Vec3, g: u8) -> CloudPoint {
        let g32 = g as u32;
        CloudPoint { x: p.x, y: p.y, z: p.z, rgb: 0xff00_0000 | g32 << 16 | g32 << 8 | g32 }
    }

    /// Its position (m).
    #[inline]
    pub fn pos(&self) -> Vec3 {
        Vec3::new(self.x, self.y, self.z)
    }

    /// Its gray level.
    #[inline]
    pub fn gray(&self) -> u8 {
        self.rgb as u8
    }
}

/// A frame's cloud: its own memory, or a lent PointCloud2 message's ([`crate::sink::Sink::lend_depth`]).
pub type CloudMap = LentMap<CloudPoint>;

/// The depth map and the valid points of one frame.
pub struct DepthFrame {
    /// Width (px).
    pub width: u32,
    /// Height (px).
    pub height: u32,
    /// Z (m) per rectified left pixel, NaN = invalid: in the frame's own buffer, or in the message a sink
    /// will send it in, when one lent its buffer for it ([`crate::sink::Sink::lend_depth`]).
    pub depth: F32Map,
    /// Valid points in the left home camera frame with their gray level (rectified left image); the first
    /// `n_points` entries are meaningful. In the frame's own buffer, or in the cloud message a sink lent.
    pub cloud: CloudMap,
    /// Pixel index of each point (row-major), to look truth up.
    pub pixel: Vec<u32>,
    /// Number of valid points (and meaningful entries of `cloud`, `pixel`).
    pub n_points: usize,
}

impl DepthFrame {
    /// A frame of `width` x `height` buffers, all depth invalid.
    pub fn new(width: u32, height: u32) -> Self {
        let n = (width * height) as usize;
        DepthFrame {
            width,
            height,
            depth: vec![f32::NAN; n].into(),
            cloud: vec![CloudPoint::default(); n].into(),
            pixel: vec![0; n],
            n_points: 0,
        }
    }

    /// A frame without buffers (no allocation): the pooled frames hold one until the output lane lends its
    /// own (see [`Work::depth`]).
    pub fn empty() -> Self {
        DepthFrame::new(0, 0)
    }

    /// Fraction of the pixels with a valid depth.
    pub fn valid_fraction(&self) -> f64 {
        self.n_points as f64 / self.depth.len() as f64
    }
}

// ---------------------------------------------------------------- the fovea

/// The foveal depth of one frame (`tasks::fovea`): a window of the rectified plane at the source frames'
/// native focal length, centred on the fixation point, with its own depth and cloud. The window is where
/// its intrinsics put it: its pixel (u, v) looks along ((u - cx) / f, (v - cy) / f, 1) in the same rectified
/// frame as the main map ([`Rectification`]).
pub struct FoveaFrame {
    /// The left window's intrinsics (native focal length; principal point placing the fixation at the centre).
    pub cam: RectifiedCamera,
    /// The right window's principal point is `cam.cx + offset_px`: the search starts there, and the full
    /// disparity is the matched one plus this offset.
    pub offset_px: f64,
    /// Disparities searched (px at the fovea's scale): `[offset_px, offset_px + range)`.
    pub search_px: [f64; 2],
    /// The fixation point (m, left home camera frame) the window is centred on.
    pub fixation_m: [f64; 3],
    /// Its distance from the midpoint of both optical centres (m).
    pub fixation_distance_m: f64,
    /// Whether the fixation was measured (both optical axes meet in front, within range); otherwise the image
    /// centre at the default distance.
    pub measured: bool,
    /// Whether the search range came from the main map's disparities in the window (else the fixation's).
    pub from_main: bool,
    /// Rectified left window (gray, row-major).
    pub left: Vec<u8>,
    /// Rectified right window.
    pub right: Vec<u8>,
    /// 1 where the left window pixel sees the raw image.
    pub valid: Vec<u8>,
    /// Full disparity (px at the fovea's scale), NaN where there is none.
    pub disparity: Vec<f32>,
    /// Depth and cloud of the window (left home camera frame).
    pub depth: DepthFrame,
    /// Whether the fovea stage filled this frame.
    pub ready: bool,
}

impl FoveaFrame {
    /// Buffers for a `width` x `height` window.
    pub fn new(width: u32, height: u32) -> Self {
        let n = (width * height) as usize;
        FoveaFrame {
            cam: RectifiedCamera { width, height, f: 1.0, cx: 0.0, cy: 0.0 },
            offset_px: 0.0,
            search_px: [0.0; 2],
            fixation_m: [f64::NAN; 3],
            fixation_distance_m: f64::NAN,
            measured: false,
            from_main: false,
            left: vec![0; n],
            right: vec![0; n],
            valid: vec![0; n],
            disparity: vec![f32::NAN; n],
            depth: DepthFrame::new(width, height),
            ready: false,
        }
    }

    /// Copies `other` (a window of the same size) into this one's buffers: no allocation.
    pub fn copy_from(&mut self, other: &FoveaFrame) {
        (self.cam, self.offset_px, self.search_px) = (other.cam, other.offset_px, other.search_px);
        (self.fixation_m, self.fixation_distance_m) = (other.fixation_m, other.fixation_distance_m);
        (self.measured, self.from_main, self.ready) = (other.measured, other.from_main, other.ready);
        self.left.copy_from_slice(&other.left);
        self.right.copy_from_slice(&other.right);
        self.valid.copy_from_slice(&other.valid);
        self.disparity.copy_from_slice(&other.disparity);
        let (d, o, n) = (&mut self.depth, &other.depth, other.depth.n_points);
        d.depth.copy_from_slice(&o.depth);
        d.cloud[..n].copy_from_slice(&o.cloud[..n]);
        d.pixel[..n].copy_from_slice(&o.pixel[..n]);
        d.n_points = n;
    }
}

// ---------------------------------------------------------------- the pooled frame, the published frame

/// One frame's messages as it moves through the stage graph. Allocated at start-up and recycled: a stage
/// writes its message into buffers that already exist, so steady state does not allocate.
pub struct Work {
    /// Pipeline sequence number (keeps increasing when a replay loops).
    pub seq: u64,
    /// The frame's `seq` in its session (before looping): the key of its ground truth.
    pub session_seq: u64,
    /// The left frame's instant (CLOCK_MONOTONIC ns): its middle row's mid-exposure (conventions.md
    /// "Time"): the frame's timestamp, and the virtual camera every row is rectified into.
    pub t_frame_ns: i64,
    /// The right frame's instant (ns).
    pub t_right_ns: i64,
    /// Row timing, speed, per-row rotations and the motion gate of this frame.
    pub motion: FrameMotion,
    /// The raw pair (gray, the source's size).
    pub raw_left: Vec<u8>,
    /// The raw right frame.
    pub raw_right: Vec<u8>,
    /// Link angles of both eyes at their frames' mid-exposure (deg, homed): the align stage's output.
    pub theta: [[f64; 3]; 2],
    /// Both eyes' poses and the extrinsic at the frame's instant: the kinematics stage's output.
    pub pose: Option<StereoPose>,
    /// The rectified pair: the rectify stage's output.
    pub rectified: RectifiedPair,
    /// Left-view disparity (px), NaN where there is none.
    pub disparity: Vec<f32>,
    /// Per-pixel confidence of the disparity in [0, 1] (0 = invalid; `abvs_disparity::confidence`), at the output
    /// resolution. Empty unless the disparity stage computes it (it sizes the pooled frames then).
    pub confidence: Vec<f32>,
    /// Why each pixel is not published (`abvs_disparity::confidence::reason`; 0 = published), when the engine scores
    /// its pixels (the validity mask). Empty otherwise, sized like `confidence`.
    pub reason: Vec<u8>,
    /// The disparity before the validity mask (NaN only where the rectified pixel does not see the raw
    /// image), when a sink asks for it ([`crate::sink::Sink::wants_dense_disparity`]) and the engine scores
    /// its pixels. Empty otherwise.
    pub dense_disparity: Vec<f32>,
    /// Depth and cloud. Filled and published on the output lane, which lends its one buffer to the frame
    /// it is working on: a buffer per pooled frame would double the pool's memory (1.6 MB a frame at
    /// 320x240) for a message that never crosses a queue. Empty everywhere else.
    pub depth: DepthFrame,
    /// The foveal depth (`tasks::fovea`), when the graph has the fovea stage (it sizes the pooled frames).
    pub fovea: Option<Box<FoveaFrame>>,
}

impl Work {
    /// Buffers for raw frames of `raw` and outputs of `out` (width, height).
    pub fn new(raw: (u32, u32), out: (u32, u32)) -> Box<Work> {
        let nr = (raw.0 * raw.1) as usize;
        let no = (out.0 * out.1) as usize;
        Box::new(Work {
            seq: 0,
            session_seq: 0,
            t_frame_ns: 0,
            t_right_ns: 0,
            motion: FrameMotion::new(),
            raw_left: vec![0; nr],
            raw_right: vec![0; nr],
            theta: [[0.0; 3]; 2],
            pose: None,
            rectified: RectifiedPair::new(out.0, out.1),
            disparity: vec![f32::NAN; no],
            confidence: Vec::new(),
            reason: Vec::new(),
            dense_disparity: Vec::new(),
            depth: DepthFrame::empty(),
            fovea: None,
        })
    }

    /// Takes a source's pair into this frame's buffers (the frame's results of a previous use are cleared).
    pub fn fill(&mut self, f: &SourcePair) {
        self.seq = f.seq;
        self.session_seq = f.session_seq;
        // the middle row's mid-exposure
        let mid = f.readout_ns / 2 + f.exposure_ns / 2;
        self.t_frame_ns = f.t_start_ns + mid;
        self.t_right_ns = f.right_t_start_ns + mid;
        let m = &mut self.motion;
        m.t_start_ns = [f.t_start_ns, f.right_t_start_ns];
        m.exposure_ns = f.exposure_ns;
        m.readout_ns = f.readout_ns;
        m.readout_anchor = f.readout_anchor;
        m.omega_rad_s = [Vector3::zeros(); 2];
        m.omega_wide_rad_s = [[Vector3::zeros(); 2]; 2];
        m.vel_m_s = [Vector3::zeros(); 2];
        m.band_theta.iter_mut().for_each(Vec::clear);
        m.band_rot.iter_mut().for_each(Vec::clear);
        m.speed_deg_s = [0.0; 2];
        m.blur_px = 0.0;
        m.gated = false;
        m.gaze = crate::gaze::GazeState::default();
        self.raw_left.copy_from_slice(f.left);
        self.raw_right.copy_from_slice(f.right);
        self.pose = None;
        self.rectified.rect = None;
        if let Some(f) = &mut self.fovea {
            f.ready = false;
        }
    }

    /// What the sinks see of this frame, once every stage ran (`None` before).
    pub fn published<'a>(&'a self, cam: &'a RectifiedCamera) -> Option<Published<'a>> {
        Some(Published {
            seq: self.seq,
            session_seq: self.session_seq,
            t_frame_ns: self.t_frame_ns,
            theta: &self.theta,
            pose: self.pose.as_ref()?,
            rect: self.rectified.rect.as_ref()?,
            cam,
            depth: &self.depth,
            left_rect: &self.rectified.left,
            right_rect: &self.rectified.right,
            disparity: &self.disparity,
            confidence: (!self.confidence.is_empty()).then_some(&self.confidence[..]),
            dense_disparity: (!self.dense_disparity.is_empty()).then_some(&self.dense_disparity[..]),
            motion: &self.motion,
            fovea: self.fovea.as_deref().filter(|f| f.ready),
        })
    }
}

/// What an output sink sees of one finished frame.
pub struct Published<'a> {
    /// Pipeline sequence number (keeps increasing when a replay loops).
    pub seq: u64,
    /// The frame's `seq` in its session (before looping): the key of its ground truth.
    pub session_seq: u64,
    /// The left frame's instant (CLOCK_MONOTONIC ns), the frame's timestamp.
    pub t_frame_ns: i64,
    /// Link angles of both eyes at their frames' mid-exposure (deg, homed).
    pub theta: &'a [[f64; 3]; 2],
    /// Both eyes' poses and the extrinsic at the frame's instant.
    pub pose: &'a StereoPose,
    /// The rectifying rotations and the baseline.
    pub rect: &'a Rectification,
    /// The rectified camera the depth is in.
    pub cam: &'a RectifiedCamera,
    /// Depth map and cloud (left home camera frame, m).
    pub depth: &'a DepthFrame,
    /// Rectified left image (gray).
    pub left_rect: &'a [u8],
    /// Rectified right image.
    pub right_rect: &'a [u8],
    /// Left-view disparity (px), NaN where there is none.
    pub disparity: &'a [f32],
    /// The disparity's confidence in [0, 1] per pixel (0 = invalid), when the run computes it.
    pub confidence: Option<&'a [f32]>,
    /// The disparity before the validity mask ([`Work::dense_disparity`]), when a sink asked for it.
    pub dense_disparity: Option<&'a [f32]>,
    /// The frame's motion: eye speeds, blur, and whether it was gated (depth all NaN, empty cloud).
    pub motion: &'a FrameMotion,
    /// The foveal depth, when the run computes one (gated with the frame: NaN, empty cloud).
    pub fovea: Option<&'a FoveaFrame>,
}
