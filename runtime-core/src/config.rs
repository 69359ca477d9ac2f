//! The runtime configuration file: what one deployment runs, in one versioned TOML file
//! (`format = "abvs-runtime/1"`) to version, review and ship. `abvs run --config FILE` runs it,
//! command-line flags override its fields, `abvs run --print-config` prints the effective
//! configuration. Unknown fields are refused with the file and line. Relative paths in a file
//! are relative to the file's directory. Field-by-field documentation: `config/fixture.toml`
//! and `config/live.toml` (shipped examples).
use crate::error::{Result, RuntimeError};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The format tag of this version of the file.
pub const FORMAT: &str = "abvs-runtime/1";

/// Where frames and encoder counts come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum SourceKind {
    /// A recorded session directory, replayed.
    Session,
    /// The eye cameras (V4L2) and the drive board's encoder stream (serial).
    Live,
    /// The closed-loop simulation of the whole head (`[source.sim]`): built by the toolkit (`abvs run --source
    /// sim`, abvs-sim), which hands the runtime its source (`abvs_runtime::Runtime::with_source`).
    Sim,
}

/// Which forward kinematics the eyes use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum FkSource {
    /// The calibrated FK models (the session's, or the calibration directory's).
    Calibrated,
    /// The ideal mechanism.
    Nominal,
    /// The true units of a synthetic session (the floor set by stereo matching alone).
    Truth,
}

/// The disparity engine.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum EngineKind {
    /// The shipped HITNet-style network through ONNX Runtime.
    Onnx,
    /// OpenCV semi-global block matching.
    Sgbm,
    /// SGBM where its own checks accept a match, the network elsewhere: the best depth on real images, at
    /// about the cost of both (`abvs_disparity::fused`).
    Fused,
    /// The network's disparity refined by a census search within a few pixels of it
    /// (`abvs_disparity::census`): the runtime's default, better than SGBM_3WAY on real images.
    #[serde(rename = "census-refine")]
    CensusRefine,
}

impl EngineKind {
    /// The name in a configuration file and on the command line.
    pub fn as_str(self) -> &'static str {
        match self {
            EngineKind::Onnx => "onnx",
            EngineKind::Sgbm => "sgbm",
            EngineKind::Fused => "fused",
            EngineKind::CensusRefine => "census-refine",
        }
    }

    /// Whether the engine scores its own pixels as it matches them (`DisparityEngine::confidence`): the
    /// validity mask and the published confidence need no second run.
    pub fn scores_pixels(self) -> bool {
        self == EngineKind::CensusRefine
    }
}

impl FkSource {
    /// The name in a configuration file and on the command line.
    pub fn as_str(self) -> &'static str {
        match self {
            FkSource::Calibrated => "calibrated",
            FkSource::Nominal => "nominal",
            FkSource::Truth => "truth",
        }
    }
}

/// Frames the MCAP recorder may fall behind by before the oldest is dropped (about 0.6 s at 25 fps).
pub const MCAP_QUEUE: usize = 16;

/// Frames the Zenoh publisher may fall behind by before the oldest is dropped: the newest matter on a network.
pub const ZENOH_QUEUE: usize = 4;

/// The Zenoh key names of the ROS 2 messages (`[bridges.zenoh] keys`, `--ros2-keys`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
pub enum Ros2Keys {
    /// zenoh-bridge-ros2dds's: the topic without its leading slash (`abvs/depth`), plain CDR samples.
    #[default]
    Bridge,
    /// rmw_zenoh's: typed keys, liveliness tokens and attachments (the runtime's `bridges::rmw_zenoh`).
    RmwZenoh,
}

/// The ROS 2 distribution the rmw_zenoh keys are for: it decides the type hashes (`[bridges.zenoh] distro`,
/// `--ros-distro`). A subscriber never matches a key with another hash.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum RosDistro {
    /// Humble: no type hashes (`TypeHashNotSupported`).
    Humble,
    /// Jazzy (the current LTS): RIHS01 hashes.
    #[default]
    Jazzy,
    /// Kilted: RIHS01 hashes, the same as Jazzy's for the five published types.
    Kilted,
}

/// A node name or namespace that ROS 2 refuses (rcl's rules: names of letters, digits and `_`, not
/// starting with a digit; a namespace `/` or `/` + such names joined by `/`).
pub fn check_node(name: &str, namespace: &str) -> std::result::Result<(), String> {
    let token_ok = |t: &str| {
        t.chars().next().is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
            && t.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
    };
    if !token_ok(name) {
        return Err(format!("node: `{name}` is not a ROS 2 node name (letters, digits, `_`; no digit first)"));
    }
    let ns_ok = namespace == "/" || namespace.strip_prefix('/').is_some_and(|r| r.split('/').all(token_ok));
    if !ns_ok {
        return Err(format!("namespace: `{namespace}` is not `/` or `/name[/name...]` (letters, digits, `_`)"));
    }
    Ok(())
}

/// One deployment: what `abvs run --config FILE` runs and `abvs_runtime::Runtime::from_config` assembles.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RuntimeConfig {
    /// The file's format tag, [`FORMAT`].
    pub format: String,
    /// `[source]`: where frames and encoder counts come from.
    pub source: SourceConfig,
    /// `[calibration]`: which FK the eyes use, and where a live run's calibration is.
    pub calibration: CalibrationConfig,
    /// `[disparity]`: the engine, its resolution and range, the left-right check.
    pub disparity: DisparityConfig,
    /// `[motion]`: the rolling-shutter correction, the motion gate, timing overrides.
    #[serde(default)]
    pub motion: MotionSettings,
    /// `[sinks]`: statistics and outputs inside this process.
    #[serde(default)]
    pub sinks: SinksConfig,
    /// `[bridges]`: publishing to other processes.
    #[serde(default)]
    pub bridges: BridgesConfig,
    /// `[gaze]`: limits on the goals that point the eyes, whoever sends them.
    #[serde(default)]
    pub gaze: GazeSettings,
    /// `[fovea]`: depth at the raw frames' native scale around the fixation point (`tasks::fovea`).
    #[serde(default)]
    pub fovea: FoveaSettings,
}

/// `[gaze]`: limits on pointing the eyes that hold for every sender (docs/gaze.md, "Who may move the eyes").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GazeSettings {
    /// The gaze service: the controller's stage after kinematics, the iceoryx2 `{prefix}/gaze/goal` and
    /// `{prefix}/gaze/state` services and Zenoh's `/abvs/gaze/state` (default on). Off (`--no-gaze`), the
    /// runtime only looks: no goal is taken, no state published, and the depth is bit-identical to a run with
    /// it on and no goals (the switch exists so that a paired benchmark can measure the service's cost).
    pub enabled: bool,
    /// Goals the controller executes per second at most, sustained (a token bucket; a goal over the limit
    /// waits, the newest one only, and one replaced while it waits is counted as `rate_limited`).
    pub max_goals_per_s: f64,
    /// Goals that may come back to back (the bucket's size).
    pub goal_burst: u32,
}

impl Default for GazeSettings {
    fn default() -> Self {
        let l = crate::params::RateLimit::default();
        GazeSettings { enabled: true, max_goals_per_s: l.max_goals_per_s, goal_burst: l.goal_burst }
    }
}

impl GazeSettings {
    /// The rate limit the gaze stage runs with.
    pub fn rate_limit(&self) -> crate::params::RateLimit {
        crate::params::RateLimit { max_goals_per_s: self.max_goals_per_s, goal_burst: self.goal_burst }
    }
}

/// `[fovea]`: depth at the raw frames' native scale where the eyes look (`tasks::fovea`): on by default, a
/// window of `width` x `height` raw-scale pixels on its own lane; the main map is the same either way.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FoveaSettings {
    /// Compute and publish the fovea.
    pub enabled: bool,
    /// Window width (px at the raw frames' scale).
    pub width: u32,
    /// Window height (px).
    pub height: u32,
    /// Widest disparity search (px at the fovea's scale, a multiple of 16).
    pub max_range_px: u32,
    /// Fixations (the closest approach of both optical axes) nearer than this are not used (m).
    pub min_distance_m: f64,
    /// Fixations farther than this are not used (m): the window goes to the image centre instead.
    pub max_distance_m: f64,
    /// Distance along the image centre's ray without a usable fixation (m).
    pub default_distance_m: f64,
    /// When the fovea's lane is behind, a frame goes on without its fovea rather than frames being dropped
    /// whole; false: every frame's fovea is computed, and an overloaded machine drops frames instead.
    pub shed_when_behind: bool,
}

impl Default for FoveaSettings {
    fn default() -> Self {
        let f = crate::params::FoveaConfig::default();
        FoveaSettings {
            enabled: true,
            width: f.width,
            height: f.height,
            max_range_px: f.max_range_px,
            min_distance_m: f.min_distance_m,
            max_distance_m: f.max_distance_m,
            default_distance_m: f.default_distance_m,
            shed_when_behind: f.shed_when_behind,
        }
    }
}

impl FoveaSettings {
    /// What the pipeline runs, `None` when off.
    pub fn fovea_config(&self) -> Option<crate::params::FoveaConfig> {
        self.enabled.then_some(crate::params::FoveaConfig {
            width: self.width,
            height: self.height,
            max_range_px: self.max_range_px,
            min_distance_m: self.min_distance_m,
            max_distance_m: self.max_distance_m,
            default_distance_m: self.default_distance_m,
            shed_when_behind: self.shed_when_behind,
        })
    }

    #[allow(clippy::neg_cmp_op_on_partial_ord)] // refuses NaN too
    fn check(&self) -> std::result::Result<(), String> {
        if !(16..=4096).contains(&self.width) || !(16..=4096).contains(&self.height) {
            return Err(format!("fovea.width/height: {}x{} is not a usable window", self.width, self.height));
        }
        if !(16..=256).contains(&self.max_range_px) || self.max_range_px % 16 != 0 {
            return Err(format!("fovea.max_range_px: {} must be a multiple of 16 in 16..=256", self.max_range_px));
        }
        let (a, b, d) = (self.min_distance_m, self.max_distance_m, self.default_distance_m);
        if !(a > 0.0 && a < b && b <= 100.0) {
            return Err(format!("fovea.min_distance_m / max_distance_m: {a} / {b} must satisfy 0 < min < max <= 100"));
        }
        if !(d > 0.0 && d <= 100.0) {
            return Err(format!("fovea.default_distance_m: {d} must be in (0, 100]"));
        }
        Ok(())
    }
}

/// `[source]`: where frames and encoder counts come from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SourceConfig {
    /// A recorded session, or the live devices.
    pub kind: SourceKind,
    /// Session directory (kind = "session").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub session: Option<PathBuf>,
    /// Frames to process (a shorter session loops, timestamps kept increasing); absent: one pass
    /// of a session, unlimited live.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frames: Option<u64>,
    /// Loop a session without end (until `seconds`, or `frames`, or the process is stopped).
    #[serde(default, rename = "loop")]
    pub looping: bool,
    /// Stop taking frames this many seconds after the start (a soak test: `loop = true, seconds = 1800`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seconds: Option<f64>,
    /// Every frame processed (queues block instead of dropping the oldest), replayed as fast as
    /// possible: offline and reproducible.
    #[serde(default)]
    pub lossless: bool,
    /// Replay at the recorded frame rate (ignored live and with lossless).
    #[serde(default = "yes")]
    pub paced: bool,
    /// `[source.live]`: the devices of a live run.
    #[serde(default)]
    pub live: LiveConfig,
    /// `[source.sim]`: the simulated head (kind = "sim"; printed only when not the default).
    #[serde(default, skip_serializing_if = "SimConfig::is_default")]
    pub sim: SimConfig,
}

/// The closed-loop simulation of the whole head (kind = "sim"; abvs-sim's `head`): the simulated drive board
/// executes the runtime's commands, every frame is rendered from the true link angles at each row's time, in
/// virtual time (lockstep, deterministic, as fast as rendering allows; always lossless).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SimConfig {
    /// Picks both units (their true physics), the stereo rig, the board's origins and the scene.
    pub seed: u64,
    /// Timed gaze goals (format: docs/gaze.md, "Gaze scripts"); absent: the eyes hold home.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gaze_script: Option<PathBuf>,
    /// Rendered frame width (px).
    pub width: u32,
    /// Rendered frame height (px).
    pub height: u32,
    /// Frame rate (Hz, virtual time).
    pub fps: f64,
    /// Exposure of every row (ms).
    pub exposure_ms: f64,
    /// Rolling-shutter readout (ms), first row's start of exposure to the last row's.
    pub readout_ms: f64,
    /// Directory of the simulated units' calibration (stereo.yaml, eye0, eye1), made by the toolkit's
    /// calibration from simulated measurements the first time and reused; absent: a directory per seed
    /// under the system's temporary directory.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub calib_dir: Option<PathBuf>,
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            seed: 1,
            gaze_script: None,
            width: 640,
            height: 480,
            fps: 25.0,
            exposure_ms: 4.0,
            readout_ms: 20.0,
            calib_dir: None,
        }
    }
}

impl SimConfig {
    fn is_default(&self) -> bool {
        *self == SimConfig::default()
    }

    #[allow(clippy::neg_cmp_op_on_partial_ord)] // refuses NaN too
    fn check(&self) -> std::result::Result<(), String> {
        if !(16..=4096).contains(&self.width) || !(16..=4096).contains(&self.height) {
            return Err(format!("source.sim.width/height: {}x{} is not a usable size", self.width, self.height));
        }
        if !(self.fps > 0.0 && self.fps <= 200.0) {
            return Err(format!("source.sim.fps (--fps): {} must be in (0, 200]", self.fps));
        }
        let frame_ms = 1e3 / self.fps;
        if !(0.0..=frame_ms).contains(&self.exposure_ms) {
            return Err(format!(
                "source.sim.exposure_ms (--exposure-ms): {} must be in [0, {frame_ms}] (one frame period)",
                self.exposure_ms
            ));
        }
        if !(0.0..=frame_ms - 4.0).contains(&self.readout_ms) {
            return Err(format!(
                "source.sim.readout_ms (--readout-ms): {} must be in [0, {}] (frame period - 4 ms)",
                self.readout_ms,
                frame_ms - 4.0
            ));
        }
        Ok(())
    }
}

fn yes() -> bool {
    true
}

/// The live devices (kind = "live").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LiveConfig {
    /// Left eye camera (V4L2 device).
    pub left: PathBuf,
    /// Right eye camera.
    pub right: PathBuf,
    /// Serial port of the drive board's encoder stream.
    pub encoders: String,
    /// Serial baud rate of the encoder stream.
    pub baud: u32,
    /// Capture width (px).
    pub width: u32,
    /// Capture height (px).
    pub height: u32,
    /// Camera frame rate (Hz).
    pub fps: u32,
    /// V4L2 FourCC: pgAA (RAW10 MIPI-packed GRBG, the OV8856 default), BA10, YUYV, NV12, ...
    pub fourcc: String,
    /// Exposure (ms); absent: read once from the camera (exposure must be manual).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub exposure_ms: Option<f64>,
    /// Rolling-shutter readout (ms), moves end-of-frame stamps to the start of exposure.
    pub readout_ms: f64,
    /// Largest left/right start-of-exposure difference of a pair (ms).
    pub pair_tolerance_ms: f64,
    /// Seconds both eyes have to home.
    pub homing_timeout_s: f64,
}

impl Default for LiveConfig {
    fn default() -> Self {
        LiveConfig {
            left: "/dev/video0".into(),
            right: "/dev/video2".into(),
            encoders: "/dev/ttyACM0".into(),
            baud: 1_000_000,
            width: 1600,
            height: 1200,
            fps: 25,
            fourcc: "pgAA".into(),
            exposure_ms: None,
            readout_ms: 30.0,
            pair_tolerance_ms: 2.0,
            homing_timeout_s: 30.0,
        }
    }
}

/// `[calibration]`: the eyes' FK and a live run's calibration directory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationConfig {
    /// Which FK the eyes use.
    pub fk: FkSource,
    /// Calibration directory (stereo.yaml, eye0, eye1) for live runs; a session brings its own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dir: Option<PathBuf>,
}

/// `[disparity]`: the engine, its resolution and range, the left-right check.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DisparityConfig {
    /// The disparity engine.
    pub engine: EngineKind,
    /// Model directory or .onnx; absent: the shipped model for the resolution.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model: Option<PathBuf>,
    /// Rectified (network) width.
    pub width: u32,
    /// Rectified (network) height.
    pub height: u32,
    /// Horizontal field of view of the rectified images (deg).
    pub rect_hfov_deg: f64,
    /// Nearest depth to match (m): sets the disparity range, f B / min_depth.
    pub min_depth_m: f64,
    /// Threads of the ONNX engine, and of OpenCV's pool (SGBM_3WAY, remap): one budget for every engine.
    pub threads: usize,
    /// Per-pixel confidence of the disparity by a left-right check (the engine run a second time on the
    /// mirrored pair: about doubles the disparity stage), published on `{prefix}/confidence`.
    #[serde(default)]
    pub confidence: bool,
    /// Drop the pixels that fail the left-right check (their depth and cloud points): runs the check.
    #[serde(default)]
    pub lr_check: bool,
    /// Largest left/right disparity disagreement (px) of a consistent match.
    #[serde(default = "default_lr_max_diff")]
    pub lr_max_diff: f64,
    /// The validity mask: depth (and cloud points) dropped where the engine's own confidence is below this,
    /// in [0, 1] (census-refine: `abvs_disparity::census_confidence`; other engines publish every pixel they match).
    /// 0 publishes every pixel, as dense as before the mask.
    #[serde(default = "default_min_confidence")]
    pub min_confidence: f64,
}

fn default_min_confidence() -> f64 {
    crate::params::DEFAULT_MIN_CONFIDENCE as f64
}

fn default_lr_max_diff() -> f64 {
    1.0
}

impl DisparityConfig {
    /// The pipeline's left-right check as this section configures it.
    pub fn check_config(&self) -> crate::params::CheckConfig {
        crate::params::CheckConfig {
            confidence: self.confidence,
            invalidate: self.lr_check,
            max_diff: self.lr_max_diff as f32,
        }
    }
}

/// `[sinks]`: statistics and outputs inside this process.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SinksConfig {
    /// Score depth against a synthetic session's ground truth every N-th point (0: off). The `abvs` program's:
    /// the scoring is offline tooling (`abvs_runtime::Runtime` adds no such sink).
    pub truth_stride: usize,
    /// Statistics as JSON.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stats_json: Option<PathBuf>,
    /// Each frame's rectified pair and depth as PNG (slow; for looking).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dump: Option<PathBuf>,
    /// rerun recording (.rrd; needs the cargo feature `rerun`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rerun: Option<PathBuf>,
    /// No latency table on stdout (what the `abvs` program prints; `abvs_runtime::Report::table` for an embedder).
    pub quiet: bool,
    /// Length of a statistics window (s): latency p50/p99, counts and resident memory per window.
    pub stats_window_s: f64,
    /// The self-check of the stereo calibration from the rectified images (`sinks::self_check`).
    pub self_check: SelfCheckSettings,
    /// MCAP recording of the ROS 2 messages (`sinks::mcap_log`).
    pub mcap: McapSettings,
}

impl Default for SinksConfig {
    fn default() -> Self {
        SinksConfig {
            truth_stride: 8,
            stats_json: None,
            dump: None,
            rerun: None,
            quiet: false,
            stats_window_s: 60.0,
            self_check: SelfCheckSettings::default(),
            mcap: McapSettings::default(),
        }
    }
}

/// `[sinks.mcap]`: the ROS 2 messages of every frame recorded as MCAP (the runtime's `ros2`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct McapSettings {
    /// The MCAP file; absent: no recording.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub file: Option<PathBuf>,
    /// Frames the writer may fall behind by before the oldest is dropped (lossless runs wait instead).
    pub queue: usize,
}

impl Default for McapSettings {
    fn default() -> Self {
        McapSettings { file: None, queue: MCAP_QUEUE }
    }
}

/// `[sinks.self_check]`: vertical disparity and relative rotation error measured from the rectified pairs
/// off the critical path (see `sinks::self_check`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SelfCheckSettings {
    /// Whether the self-check runs.
    pub enabled: bool,
    /// Check every n-th frame.
    pub every: u64,
    /// Per-frame CSV log (seq, time, both eyes' link angles, vertical px, rotation error).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub log: Option<PathBuf>,
    /// Warn when the rotation error (median over `warn_frames` checked frames) exceeds this (deg).
    pub threshold_deg: f64,
    /// Checked frames the rotation error's median is taken over.
    pub warn_frames: u32,
}

impl Default for SelfCheckSettings {
    fn default() -> Self {
        let d = crate::params::SelfCheckConfig::default();
        SelfCheckSettings {
            enabled: true,
            every: d.every,
            log: None,
            threshold_deg: d.threshold_deg,
            warn_frames: d.warn_frames,
        }
    }
}

/// `[bridges]`: publishing to other processes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct BridgesConfig {
    /// `[bridges.iceoryx]`: depth, confidence and cloud over shared memory on this computer.
    pub iceoryx: IceoryxConfig,
    /// `[bridges.zenoh]`: the ROS 2 messages to other computers.
    pub zenoh: ZenohSettings,
}

/// `[bridges.zenoh]`: the ROS 2 messages published over Zenoh (see `bridges::zenoh`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ZenohSettings {
    /// Whether the messages are published over Zenoh.
    pub enabled: bool,
    /// Endpoints to connect to, e.g. `tcp/192.168.1.20:7447` (added to the configuration file's).
    pub connect: Vec<String>,
    /// Endpoints to listen on, e.g. `tcp/0.0.0.0:7447` (added to the configuration file's).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub listen: Vec<String>,
    /// A standard Zenoh configuration file (JSON5): TLS/mTLS, user/password authentication, access control
    /// (`access_control`) in Zenoh's own format; absent: Zenoh's defaults (a peer, open to the network).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub config: Option<PathBuf>,
    /// Take gaze goals from `/abvs/gaze/goal` (geometry_msgs/msg/PointStamped) over Zenoh: goals from other
    /// machines move the motors. Off by default; on, the runtime refuses to start unless `config` sets
    /// authentication or an access control, or `insecure` is set.
    #[serde(default)]
    pub accept_gaze_goals: bool,
    /// With `accept_gaze_goals`: start without authentication or access control (anyone who reaches the
    /// session may point the eyes; the start-up line says so).
    #[serde(default)]
    pub insecure: bool,
    /// Frames the publisher may fall behind by before the oldest is dropped.
    pub queue: usize,
    /// Key names: `bridge` (zenoh-bridge-ros2dds's) or `rmw-zenoh` (a ROS 2 node on rmw_zenoh).
    pub keys: Ros2Keys,
    /// `rmw-zenoh`: the ROS 2 distribution whose type hashes the keys carry (humble, jazzy, kilted).
    pub distro: RosDistro,
    /// `rmw-zenoh`: the ROS domain id (`ROS_DOMAIN_ID` of the ROS 2 side).
    pub domain: u32,
    /// `rmw-zenoh`: the node's name.
    pub node: String,
    /// `rmw-zenoh`: the node's namespace (the topics are absolute: it names the node only).
    pub namespace: String,
    /// The large messages (depth images, clouds) written into Zenoh shared memory: a subscriber on this
    /// computer whose session enables it gets a descriptor instead of the bytes; others get the bytes as
    /// without it. `false` also turns Zenoh's own shared memory off in the session.
    pub shared_memory: bool,
}

impl Default for ZenohSettings {
    fn default() -> Self {
        ZenohSettings {
            enabled: false,
            connect: Vec::new(),
            listen: Vec::new(),
            config: None,
            accept_gaze_goals: false,
            insecure: false,
            queue: ZENOH_QUEUE,
            keys: Ros2Keys::default(),
            distro: RosDistro::default(),
            domain: 0,
            node: "abvs".into(),
            namespace: "/".into(),
            shared_memory: true,
        }
    }
}

/// `[bridges.iceoryx]`: depth, confidence and cloud over iceoryx2 shared memory (the runtime's `bridges::iceoryx`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IceoryxConfig {
    /// Whether the runtime publishes there.
    pub enabled: bool,
    /// Services `{prefix}/depth`, `{prefix}/cloud` (with `[disparity] confidence`, `{prefix}/confidence`) and
    /// their events.
    pub service_prefix: String,
}

impl Default for IceoryxConfig {
    fn default() -> Self {
        IceoryxConfig { enabled: true, service_prefix: "abvs".into() }
    }
}

/// Eyes that move while they expose (`tasks::motion`): the per-row correction, the motion gate, and the
/// timing of the eyes where it is measured rather than taken from the source and the FK models.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MotionSettings {
    /// Rectify each row with the eye's pose when it exposed (frames with a rolling-shutter readout).
    pub rolling_shutter: bool,
    /// Row bands of that correction (1 ..= 64).
    pub row_bands: usize,
    /// Publish a frame's depth invalid (NaN, empty cloud, header flag) when its motion blur exceeds this
    /// many rectified pixels (the faster eye's speed x exposure); a large value never gates.
    pub gate_blur_px: f64,
    /// Rolling-shutter readout (ms), overriding the session's (session.toml) or the cameras'
    /// (`[source.live] readout_ms`): e.g. measured by `abvs calib self-check`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub readout_ms: Option<f64>,
    /// encoder_time_offset (ms: encoder stamps this much late), one value or `[left, right]`, overriding the
    /// session's (session.toml `time_offset_ms`) and the FK models'.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub time_offset_ms: Option<crate::session::TimeOffsetMs>,
}

impl Default for MotionSettings {
    fn default() -> Self {
        let m = crate::params::MotionConfig::default();
        MotionSettings {
            rolling_shutter: m.rolling_shutter,
            row_bands: m.bands,
            gate_blur_px: m.gate_blur_px,
            readout_ms: None,
            time_offset_ms: None,
        }
    }
}

impl MotionSettings {
    /// What the pipeline's stages take.
    pub fn motion_config(&self) -> crate::params::MotionConfig {
        crate::params::MotionConfig {
            rolling_shutter: self.rolling_shutter,
            bands: self.row_bands,
            gate_blur_px: self.gate_blur_px,
            time_offset_s: self.time_offset_ms.map(|t| t.per_eye().map(|t| t * 1e-3)),
        }
    }

    #[allow(clippy::neg_cmp_op_on_partial_ord)] // refuses NaN too
    fn check(&self) -> std::result::Result<(), String> {
        if !(1..=crate::messages::MAX_ROW_BANDS).contains(&self.row_bands) {
            return Err(format!(
                "motion.row_bands: {} must be in 1..={}",
                self.row_bands,
                crate::messages::MAX_ROW_BANDS
            ));
        }
        if !(self.gate_blur_px > 0.0) {
            return Err(format!("motion.gate_blur_px: {} must be positive", self.gate_blur_px));
        }
        if let Some(r) = self.readout_ms {
            if !(0.0..=1000.0).contains(&r) {
                return Err(format!("motion.readout_ms: {r} must be in [0, 1000]"));
            }
        }
        if let Some(t) = &self.time_offset_ms {
            t.check("motion.time_offset_ms")?;
        }
        Ok(())
    }
}

impl RuntimeConfig {
    /// The default deployment: replay `session` with the shipped network refined by a census search at
    /// 640x480, the best depth this 2-core machine sustains at 25 fps (runtime/BENCHMARKS.md,
    /// `scripts/bench_depth.sh`).
    pub fn for_session(session: PathBuf) -> Self {
        RuntimeConfig {
            format: FORMAT.into(),
            source: SourceConfig {
                kind: SourceKind::Session,
                session: Some(session),
                frames: None,
                looping: false,
                seconds: None,
                lossless: false,
                paced: true,
                live: LiveConfig::default(),
                sim: SimConfig::default(),
            },
            calibration: CalibrationConfig { fk: FkSource::Calibrated, dir: None },
            disparity: DisparityConfig {
                engine: EngineKind::CensusRefine,
                model: None,
                width: 640,
                height: 480,
                rect_hfov_deg: 100.0,
                min_depth_m: 0.2,
                threads: 2,
                confidence: false,
                lr_check: false,
                lr_max_diff: default_lr_max_diff(),
                min_confidence: default_min_confidence(),
            },
            motion: MotionSettings::default(),
            sinks: SinksConfig::default(),
            bridges: BridgesConfig::default(),
            gaze: GazeSettings::default(),
            fovea: FoveaSettings::default(),
        }
    }

    /// Parses a configuration; errors name `origin`, the line and the field.
    pub fn from_toml_str(text: &str, origin: &Path) -> Result<Self> {
        let file = |line: Option<u64>, msg: String| RuntimeError::File { path: origin.to_path_buf(), line, msg };
        let mut c: RuntimeConfig = toml::from_str(text).map_err(|e| {
            let line = e.span().map(|s| text[..s.start.min(text.len())].matches('\n').count() as u64 + 1);
            file(line, e.message().to_string())
        })?;
        if c.format != FORMAT {
            let line = text.lines().position(|l| l.trim_start().starts_with("format")).map(|l| l as u64 + 1);
            return Err(file(line, format!("format: `{}`, this abvs reads `{FORMAT}`", c.format)));
        }
        // Relative paths are relative to the file.
        if let Some(base) = origin.parent() {
            let fix = |p: &mut PathBuf| {
                if p.is_relative() {
                    *p = base.join(&*p);
                }
            };
            c.source.session.as_mut().map(fix);
            c.source.sim.gaze_script.as_mut().map(fix);
            c.source.sim.calib_dir.as_mut().map(fix);
            c.calibration.dir.as_mut().map(fix);
            c.disparity.model.as_mut().map(fix);
            c.sinks.stats_json.as_mut().map(fix);
            c.sinks.dump.as_mut().map(fix);
            c.sinks.rerun.as_mut().map(fix);
            c.sinks.self_check.log.as_mut().map(fix);
            c.sinks.mcap.file.as_mut().map(fix);
            c.bridges.zenoh.config.as_mut().map(fix);
        }
        c.check().map_err(|m| file(None, m))?;
        Ok(c)
    }

    /// Reads and parses a configuration file (see [`RuntimeConfig::from_toml_str`]).
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| RuntimeError::File {
            path: path.to_path_buf(),
            line: None,
            msg: e.to_string(),
        })?;
        Self::from_toml_str(&text, path)
    }

    /// Values no deployment can run with.
    pub fn check(&self) -> std::result::Result<(), String> {
        let d = &self.disparity;
        if !(16..=4096).contains(&d.width) || !(16..=4096).contains(&d.height) {
            return Err(format!("disparity.width/height: {}x{} is not a usable resolution", d.width, d.height));
        }
        if !(d.rect_hfov_deg > 10.0 && d.rect_hfov_deg < 170.0) {
            return Err(format!("disparity.rect_hfov_deg: {} must be in (10, 170)", d.rect_hfov_deg));
        }
        if !(d.min_depth_m > 0.01 && d.min_depth_m.is_finite()) {
            return Err(format!("disparity.min_depth_m: {} must be > 0.01 m", d.min_depth_m));
        }
        if d.threads == 0 || d.threads > 256 {
            return Err(format!("disparity.threads: {} must be in 1..=256", d.threads));
        }
        let limit = crate::params::MAX_DIFF_LIMIT as f64;
        if !(d.lr_max_diff > 0.0 && d.lr_max_diff <= limit) {
            return Err(format!("disparity.lr_max_diff: {} must be in (0, {limit}] px", d.lr_max_diff));
        }
        if !(0.0..=1.0).contains(&d.min_confidence) {
            return Err(format!("disparity.min_confidence: {} must be in [0, 1]", d.min_confidence));
        }
        if let Some(t) = self.source.seconds {
            if !(t > 0.0 && t <= 1e7) {
                return Err(format!("source.seconds: {t} must be in (0, 1e7]"));
            }
        }
        let sc = &self.sinks.self_check;
        if sc.every == 0 || sc.warn_frames == 0 || !(sc.threshold_deg > 0.0) {
            return Err("sinks.self_check: every and warn_frames must be at least 1, threshold_deg positive".into());
        }
        for (what, q) in
            [("sinks.mcap.queue", self.sinks.mcap.queue), ("bridges.zenoh.queue", self.bridges.zenoh.queue)]
        {
            if !(1..=1024).contains(&q) {
                return Err(format!("{what}: {q} must be in 1..=1024"));
            }
        }
        let z = &self.bridges.zenoh;
        check_node(&z.node, &z.namespace).map_err(|m| format!("bridges.zenoh.{m}"))?;
        if z.domain > 232 {
            return Err(format!("bridges.zenoh.domain: {} must be in 0..=232 (ROS 2 domain ids)", z.domain));
        }
        if z.insecure && !z.accept_gaze_goals {
            return Err("bridges.zenoh.insecure: only meaningful with accept_gaze_goals = true".into());
        }
        self.gaze.rate_limit().check()?;
        if !self.gaze.enabled && z.accept_gaze_goals {
            return Err("bridges.zenoh.accept_gaze_goals: needs the gaze service (gaze.enabled = false)".into());
        }
        if !self.gaze.enabled && self.source.kind == SourceKind::Sim {
            return Err("gaze.enabled = false: the simulated head runs in lockstep with the gaze stage".into());
        }
        self.motion.check()?;
        if self.source.kind == SourceKind::Sim {
            self.source.sim.check()?;
        }
        self.fovea.check()?;
        let w = self.sinks.stats_window_s;
        if !(0.01..=86400.0).contains(&w) {
            return Err(format!("sinks.stats_window_s: {w} must be in [0.01, 86400]"));
        }
        match self.source.kind {
            SourceKind::Session if self.source.session.is_none() => {
                Err("source.session: a session directory is needed for kind = \"session\"".into())
            }
            SourceKind::Live if self.calibration.dir.is_none() => {
                Err("calibration.dir: live runs need a calibration directory".into())
            }
            SourceKind::Live if self.calibration.fk == FkSource::Truth => {
                Err("calibration.fk: `truth` needs a synthetic session, not live devices".into())
            }
            SourceKind::Sim if self.calibration.fk == FkSource::Truth => Err(
                "calibration.fk: `truth` is not offered in the simulation (it scores calibrated FK against the truth)"
                    .into(),
            ),
            _ => Ok(()),
        }
    }

    /// The configuration as TOML (what `--print-config` prints).
    pub fn to_toml_string(&self) -> String {
        toml::to_string_pretty(self).expect("a runtime configuration serialises")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_refusals() {
        let c = RuntimeConfig::for_session("/data/s".into());
        let back = RuntimeConfig::from_toml_str(&c.to_toml_string(), Path::new("/etc/abvs/r.toml")).unwrap();
        assert_eq!(back, c);
        let bad = c.to_toml_string().replace("[disparity]", "[disparity]\nmax_disp = 3");
        let e = RuntimeConfig::from_toml_str(&bad, Path::new("r.toml")).unwrap_err().to_string();
        let line = bad.lines().position(|l| l.starts_with("max_disp")).unwrap() + 1;
        assert!(e.contains(&format!("r.toml:{line}")) && e.contains("max_disp"), "{e}");
        let e = RuntimeConfig::from_toml_str(
            &c.to_toml_string().replace("abvs-runtime/1", "abvs-runtime/9"),
            Path::new("r.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("abvs-runtime/9"), "{e}");
        let e = RuntimeConfig::from_toml_str(
            &c.to_toml_string().replace("threads = 2", "threads = \"two\""),
            Path::new("r.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("r.toml:") && e.contains("invalid type"), "{e}");
        let e = RuntimeConfig::from_toml_str(
            &c.to_toml_string().replace("min_depth_m = 0.2", "min_depth_m = 0.0"),
            Path::new("r.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("min_depth_m"), "{e}");
        // the left-right check: absent fields take their defaults, a bad range is refused
        let old = c.to_toml_string().replace("confidence = false\n", "").replace("lr_max_diff = 1.0\n", "");
        assert!(!old.contains("lr_max_diff"), "{old}");
        assert_eq!(RuntimeConfig::from_toml_str(&old, Path::new("/etc/abvs/r.toml")).unwrap(), c);
        let on = c.to_toml_string().replace("confidence = false", "confidence = true");
        let on = RuntimeConfig::from_toml_str(&on, Path::new("/etc/abvs/r.toml")).unwrap();
        assert!(on.disparity.check_config().confidence && !on.disparity.check_config().invalidate);
        let e = RuntimeConfig::from_toml_str(
            &c.to_toml_string().replace("lr_max_diff = 1.0", "lr_max_diff = 0.0"),
            Path::new("r.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("lr_max_diff"), "{e}");
        // the validity mask: absent takes the documented default, out of [0, 1] is refused
        let d = crate::params::DEFAULT_MIN_CONFIDENCE as f64;
        assert_eq!(c.disparity.min_confidence, d);
        let line = format!("min_confidence = {d}\n");
        assert!(c.to_toml_string().contains(&line));
        let old = c.to_toml_string().replace(&line, "");
        assert_eq!(RuntimeConfig::from_toml_str(&old, Path::new("r.toml")).unwrap(), c);
        let e = RuntimeConfig::from_toml_str(
            &c.to_toml_string().replace(&line, "min_confidence = 1.5\n"),
            Path::new("r.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("min_confidence"), "{e}");
        // Relative paths are the file's.
        let rel = c.to_toml_string().replace("/data/s", "sessions/a");
        let r = RuntimeConfig::from_toml_str(&rel, Path::new("/etc/abvs/r.toml")).unwrap();
        assert_eq!(r.source.session.unwrap(), Path::new("/etc/abvs/sessions/a"));
    }

    #[test]
    fn node_names() {
        assert!(check_node("abvs", "/").is_ok() && check_node("_eyes2", "/robot/head_1").is_ok());
        for (name, ns) in
            [("2abvs", "/"), ("ab-vs", "/"), ("", "/"), ("abvs", ""), ("abvs", "robot"), ("abvs", "/a//b")]
        {
            assert!(check_node(name, ns).is_err(), "{name:?} {ns:?}");
        }
        assert!(check_node("abvs", "/robot/").is_err());
    }
}
