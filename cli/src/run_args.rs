//! `abvs run`'s flags, and the runtime configuration they make: the defaults (the embedded fixture), then
//! `--config`, then every flag given on the command line.
use std::path::PathBuf;

use abvs_runtime::shipped::shipped;
use abvs_runtime_core::config::{EngineKind, FkSource, RuntimeConfig, SourceKind};
use anyhow::Context;
use clap::parser::ValueSource;
use clap::{ArgMatches, Args};

#[derive(Args)]
pub struct RunArgs {
    /// Runtime configuration file (`format = "abvs-runtime/1"`, see config/fixture.toml); flags given
    /// on the command line override its fields.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Print the effective configuration (defaults, then --config, then flags) as TOML and exit.
    #[arg(long)]
    pub print_config: bool,
    /// Session directory to replay (default: the embedded fixture, fixtures/session).
    #[arg(long, conflicts_with = "live")]
    pub session: Option<PathBuf>,
    /// Run on the live eyes (V4L2 cameras and the drive board, see the device options) instead of a
    /// recorded session; needs --calib.
    #[arg(long, requires = "calib")]
    pub live: bool,
    /// With --live: calibration directory (stereo.yaml, eye0, eye1), as `abvs record` uses.
    #[arg(long)]
    pub calib: Option<PathBuf>,
    /// Where frames come from: a recorded session (--session), the live eyes (--live), or `sim`: the
    /// closed-loop simulation of the whole head (a simulated drive board executes the runtime's commands, every
    /// frame rendered from the true link angles; virtual time, deterministic, lossless; `[source.sim]`).
    #[arg(long, value_enum, conflicts_with_all = ["session", "live"])]
    pub source: Option<SourceKind>,
    /// With --source sim: picks the units, the rig and the scene.
    #[arg(long, value_parser = crate::args::count(0u64, u64::MAX / 1_000_004))]
    pub seed: Option<u64>,
    /// With --source sim: timed gaze goals to play (format: docs/gaze.md, "Gaze scripts"); without, the eyes
    /// hold home.
    #[arg(long, value_name = "FILE")]
    pub gaze_script: Option<PathBuf>,
    /// With --source sim: where the simulated units' calibration is made once and reused (default: a
    /// directory per seed and size under the temporary directory).
    #[arg(long, value_name = "DIR")]
    pub sim_calib: Option<PathBuf>,
    #[command(flatten)]
    pub devices: crate::record::DeviceArgs,
    /// Number of frames (at least 1; the session loops when shorter, timestamps kept increasing); default one pass.
    #[arg(long, value_parser = crate::args::count(1u64, u64::MAX))]
    pub frames: Option<u64>,
    /// Loop the session without end: until --seconds (or --frames), or until stopped.
    #[arg(long = "loop")]
    pub looping: bool,
    /// Stop taking frames this many seconds after the start (s, above 0 up to 1e9; with --loop: a soak test)
    /// [default: no limit: one pass, or --frames].
    #[arg(long, value_parser = crate::args::seconds())]
    pub seconds: Option<f64>,
    /// Length of a statistics window (s, above 0 up to 1e9): latency p50/p99, counts and resident memory (RSS)
    /// per window, in the table and the stats JSON (`windows`, `rss`).
    #[arg(long, default_value_t = 60.0, value_parser = crate::args::seconds())]
    pub stats_window: f64,
    /// Write the statistics as JSON.
    #[arg(long)]
    pub stats_json: Option<PathBuf>,
    /// Disparity engine: census-refine (the shipped network and SGBM's checked matches at its resolution,
    /// refined by a census search: better than SGBM on real images, at about a third of its time in the
    /// runtime), onnx (the network alone), sgbm (OpenCV SGBM_3WAY), fused (SGBM where its checks accept a
    /// match, the network elsewhere; costs both).
    #[arg(long, value_enum, default_value = "census-refine")]
    pub engine: EngineKind,
    /// Disparity model directory or .onnx (default: models/hitnet/hitnet-s at 320x240, hitnet-m at 640x480).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Network resolution "WxH" (640x480 or 320x240 for the shipped models).
    #[arg(long, default_value = "640x480")]
    pub resolution: String,
    /// Horizontal field of view of the rectified images (deg, 10 to 170).
    #[arg(long, default_value_t = 100.0, value_parser = crate::args::finite_in(10.0, 170.0))]
    pub rect_hfov: f64,
    /// FK used for the eyes: the session's calibrated models, the ideal mechanism (nominal), or the true units
    /// of a synthetic session (truth: the floor set by stereo matching alone).
    #[arg(long, value_enum, default_value = "calibrated")]
    pub fk: FkSource,
    /// Process every frame (queues block instead of dropping the oldest) and replay as fast as possible.
    #[arg(long)]
    pub lossless: bool,
    /// Do not pace the replay at the recorded frame rate.
    #[arg(long)]
    pub no_pace: bool,
    /// Nearest depth to match (m, up to 100): sets the disparity range f B / min_depth.
    #[arg(long, default_value_t = 0.2, value_parser = crate::args::positive_up_to(100.0))]
    pub min_depth: f64,
    /// Threads of the ONNX engine (1 to 256).
    #[arg(long, default_value_t = 2, value_parser = crate::args::count(1usize, 256))]
    pub threads: usize,
    /// Per-pixel confidence of the disparity by a left-right check (the engine runs a second time on the
    /// mirrored pair: about doubles the disparity stage), published on the iceoryx2 service {prefix}/confidence.
    #[arg(long)]
    pub confidence: bool,
    /// Drop the pixels that fail the left-right check (their match disagrees by more than
    /// [disparity] lr_max_diff px, 1 by default, or leaves the right image) from depth and cloud.
    #[arg(long)]
    pub lr_check: bool,
    /// The validity mask: depth and cloud points dropped where the engine's own confidence (census-refine's,
    /// computed as it matches: no second run) is below C, in [0, 1]; 0 publishes every pixel (the dense map,
    /// bit for bit). Default: [disparity] min_confidence, 0.65.
    #[arg(long, value_name = "C", value_parser = crate::args::finite_in(0.0, 1.0))]
    pub min_confidence: Option<f64>,
    /// Score depth against the session's ground truth every N-th point (synthetic sessions; 0: off).
    #[arg(long, default_value_t = 8, value_parser = crate::args::count(0usize, 1_000_000))]
    pub truth_stride: usize,
    /// Write each frame's rectified pair and depth as PNG into this directory (slow; for looking).
    #[arg(long)]
    pub dump: Option<PathBuf>,
    /// Log rectified images, depth, the cloud and both moving camera frustums to this rerun file (.rrd;
    /// needs the cargo feature `rerun`).
    #[arg(long)]
    pub rerun: Option<PathBuf>,
    /// Record the ROS 2 messages (depth, camera info, cloud, tf, joint states) to this MCAP file
    /// (profile ros2, readable by Foxglove and `ros2 bag`).
    #[arg(long)]
    pub mcap: Option<PathBuf>,
    /// Publish the ROS 2 messages over Zenoh (topics /abvs/depth, /abvs/camera_info, /abvs/points, /tf,
    /// /abvs/joint_states; key names: --ros2-keys).
    #[arg(long)]
    pub zenoh: bool,
    /// Zenoh endpoint to connect to, e.g. tcp/192.168.1.20:7447 (repeatable; implies --zenoh).
    #[arg(long, value_name = "ENDPOINT")]
    pub zenoh_connect: Vec<String>,
    /// A standard Zenoh configuration file (JSON5; implies --zenoh): TLS, user/password, access control.
    #[arg(long, value_name = "FILE")]
    pub zenoh_config: Option<PathBuf>,
    /// Zenoh endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable; implies --zenoh).
    #[arg(long, value_name = "ENDPOINT")]
    pub zenoh_listen: Vec<String>,
    /// Take gaze goals from other machines on /abvs/gaze/goal over Zenoh (PointStamped). Refused unless the
    /// Zenoh configuration authenticates peers or enables an access control, or --zenoh-insecure.
    #[arg(long)]
    pub zenoh_gaze_goals: bool,
    /// With --zenoh-gaze-goals: accept goals from anyone who reaches the session (no authentication).
    #[arg(long)]
    pub zenoh_insecure: bool,
    /// Zenoh key names: `bridge` (zenoh-bridge-ros2dds's) or `rmw-zenoh` (a ROS 2 node that rmw_zenoh
    /// systems see directly; implies --zenoh).
    #[arg(long, value_enum)]
    pub ros2_keys: Option<abvs_runtime_core::config::Ros2Keys>,
    /// The ROS 2 distribution whose type hashes the rmw-zenoh keys carry.
    #[arg(long, value_enum)]
    pub ros_distro: Option<abvs_runtime_core::config::RosDistro>,
    /// Do not publish over iceoryx2.
    #[arg(long)]
    pub no_publish: bool,
    /// Turn the gaze service off (`[gaze] enabled = false`): no goals taken, no gaze state published; the
    /// depth is the same as with it on and no goals (for the paired benchmark of its cost).
    #[arg(long)]
    pub no_gaze: bool,
    /// iceoryx2 service name prefix (services {prefix}/depth, {prefix}/cloud, with --confidence
    /// {prefix}/confidence).
    #[arg(long, default_value = "abvs")]
    pub service_prefix: String,
    /// Do not print the latency table.
    #[arg(long)]
    pub quiet: bool,
    /// Check the stereo calibration from the rectified images off the critical path: vertical disparity of
    /// matched features and the relative rotation error (stats JSON `self_check`, a warning when it persists).
    /// On by default (a drift monitor that is off monitors nothing); kept for configurations that turn it off.
    #[arg(long, conflicts_with = "no_self_check")]
    pub self_check: bool,
    /// Turn the self-check off (it runs on idle CPU time only; off saves that and its thread).
    #[arg(long, conflicts_with_all = ["self_check_every", "self_check_log"])]
    pub no_self_check: bool,
    /// Rolling-shutter correction: rectify each row with the eye's pose when it exposed (on by default
    /// wherever the frames have a readout; off: one pose per frame, for comparison).
    #[arg(long, value_enum, value_name = "on|off")]
    pub rolling_shutter: Option<OnOff>,
    /// Motion gate (rectified px, above 0 up to 1e9): frames whose blur (the faster eye's speed x exposure)
    /// exceeds this are published with depth NaN and an empty cloud, flagged in the header [default: 3, or
    /// the configuration's [motion] gate_blur_px].
    #[arg(long, value_name = "PX", value_parser = crate::args::positive_up_to(1e9))]
    pub motion_gate_px: Option<f64>,
    /// encoder_time_offset of both eyes (ms, -1000 to 1000; the encoder stream is stamped this much late),
    /// overriding the FK models' (e.g. a timing measured by `abvs calib self-check`, or a wrong one on
    /// purpose) [default: the configuration's [motion] time_offset_ms, else the session's, else the FK
    /// models']. (`--readout-ms` overrides the
    /// session's or the cameras' rolling-shutter readout the same way.)
    #[arg(long, value_name = "MS", allow_negative_numbers = true, value_parser = crate::args::finite_in(-1000.0, 1000.0))]
    pub time_offset_ms: Option<f64>,
    /// The fovea: depth at the raw frames' native scale around the fixation point, a window of WxH raw pixels
    /// (on by default at 320x240; `off`: the main map alone, published as before) [default: 320x240].
    #[arg(long, value_name = "off|WxH")]
    pub fovea: Option<String>,
    /// Self-check every N-th frame (at least 1; implies --self-check).
    #[arg(long, value_parser = crate::args::count(1u64, u64::MAX))]
    pub self_check_every: Option<u64>,
    /// Per-frame self-check log as CSV: seq, time, both eyes' link angles, vertical px, rotation error
    /// (implies --self-check).
    #[arg(long)]
    pub self_check_log: Option<PathBuf>,
}

/// A switch on the command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum OnOff {
    On,
    Off,
}

impl RunArgs {
    /// The outputs given as flags, before the run: a soak must not lose its statistics at the end.
    pub fn check(&self) -> anyhow::Result<()> {
        use abvs_runtime::outputs::{check_dir_creatable, check_file_writable};
        for (flag, p) in [
            ("--stats-json", &self.stats_json),
            ("--self-check-log", &self.self_check_log),
            ("--mcap", &self.mcap),
            ("--rerun", &self.rerun),
        ] {
            if let Some(p) = p {
                check_file_writable(flag, p)?;
            }
        }
        if let Some(d) = &self.dump {
            check_dir_creatable("--dump", d)?;
        }
        Ok(())
    }
}

fn parse_resolution(s: &str) -> anyhow::Result<(u32, u32)> {
    let (w, h) = s.split_once('x').with_context(|| format!("--resolution `{s}`: expected WxH, e.g. 320x240"))?;
    Ok((w.parse().context("--resolution width")?, h.parse().context("--resolution height")?))
}

/// The effective configuration: the defaults (the embedded fixture), then `--config`, then
/// every flag given on the command line (`m` tells which were).
pub fn effective_config(a: &RunArgs, m: &ArgMatches) -> anyhow::Result<RuntimeConfig> {
    let mut c = match &a.config {
        Some(p) => RuntimeConfig::load(p)?,
        None => RuntimeConfig::for_session(shipped("fixtures/session")),
    };
    let given = |id: &str| m.value_source(id) == Some(ValueSource::CommandLine);
    // Paths from the command line are the working directory's: made absolute, so a printed
    // configuration means the same from anywhere.
    let abs = |p: &PathBuf| std::path::absolute(p).unwrap_or_else(|_| p.clone());
    if given("session") {
        c.source.kind = SourceKind::Session;
        c.source.session = a.session.as_ref().map(abs);
    }
    if a.live {
        c.source.kind = SourceKind::Live;
    }
    if let Some(k) = a.source {
        c.source.kind = k;
    }
    let sim = &mut c.source.sim;
    if let Some(s) = a.seed {
        sim.seed = s;
    }
    if given("gaze_script") {
        sim.gaze_script = a.gaze_script.as_ref().map(abs);
    }
    if given("sim_calib") {
        sim.calib_dir = a.sim_calib.as_ref().map(abs);
    }
    if given("calib") {
        c.calibration.dir = a.calib.as_ref().map(abs);
    }
    let d = &a.devices;
    let l = &mut c.source.live;
    if given("left") {
        l.left = abs(&d.left);
    }
    if given("right") {
        l.right = abs(&d.right);
    }
    if given("encoders") {
        l.encoders = d.encoders.clone();
    }
    if given("baud") {
        l.baud = d.baud;
    }
    // (the camera flags describe the simulated head's cameras too)
    let sim = &mut c.source.sim;
    if given("width") {
        (l.width, sim.width) = (d.width, d.width);
    }
    if given("height") {
        (l.height, sim.height) = (d.height, d.height);
    }
    if given("fps") {
        (l.fps, sim.fps) = (d.fps, f64::from(d.fps));
    }
    if given("fourcc") {
        l.fourcc = d.fourcc.clone();
    }
    if given("exposure_ms") {
        l.exposure_ms = d.exposure_ms;
        if let Some(e) = d.exposure_ms {
            sim.exposure_ms = e;
        }
    }
    if given("readout_ms") {
        // the cameras' readout, and the per-row correction's for a replay as for live
        l.readout_ms = d.readout_ms;
        sim.readout_ms = d.readout_ms;
        c.motion.readout_ms = Some(d.readout_ms);
    }
    if let Some(r) = a.rolling_shutter {
        c.motion.rolling_shutter = r == OnOff::On;
    }
    if let Some(px) = a.motion_gate_px {
        c.motion.gate_blur_px = px;
    }
    if given("time_offset_ms") {
        c.motion.time_offset_ms = a.time_offset_ms.map(abvs_runtime_core::session::TimeOffsetMs::Both);
    }
    if given("pair_tolerance_ms") {
        l.pair_tolerance_ms = d.pair_tolerance_ms;
    }
    if given("homing_timeout") {
        l.homing_timeout_s = d.homing_timeout;
    }
    if given("frames") {
        c.source.frames = a.frames;
    }
    if a.looping {
        c.source.looping = true;
    }
    if given("seconds") {
        c.source.seconds = a.seconds;
    }
    if given("stats_window") {
        c.sinks.stats_window_s = a.stats_window;
    }
    if a.lossless {
        c.source.lossless = true;
    }
    if a.no_pace {
        c.source.paced = false;
    }
    if given("engine") {
        c.disparity.engine = a.engine;
    }
    if given("model") {
        c.disparity.model = a.model.as_ref().map(abs);
    }
    if given("resolution") {
        (c.disparity.width, c.disparity.height) = parse_resolution(&a.resolution)?;
    }
    if given("rect_hfov") {
        c.disparity.rect_hfov_deg = a.rect_hfov;
    }
    if given("min_depth") {
        c.disparity.min_depth_m = a.min_depth;
    }
    if given("threads") {
        c.disparity.threads = a.threads;
    }
    if a.confidence {
        c.disparity.confidence = true;
    }
    if a.lr_check {
        c.disparity.lr_check = true;
    }
    if let Some(m) = a.min_confidence {
        c.disparity.min_confidence = m;
    }
    if given("fk") {
        c.calibration.fk = a.fk;
    }
    if given("truth_stride") {
        c.sinks.truth_stride = a.truth_stride;
    }
    if given("stats_json") {
        c.sinks.stats_json = a.stats_json.as_ref().map(abs);
    }
    if given("dump") {
        c.sinks.dump = a.dump.as_ref().map(abs);
    }
    if given("rerun") {
        c.sinks.rerun = a.rerun.as_ref().map(abs);
    }
    if a.quiet {
        c.sinks.quiet = true;
    }
    let sc = &mut c.sinks.self_check;
    if a.self_check || a.self_check_every.is_some() || a.self_check_log.is_some() {
        sc.enabled = true;
    }
    if a.no_self_check {
        sc.enabled = false;
    }
    if let Some(n) = a.self_check_every {
        sc.every = n;
    }
    if given("self_check_log") {
        sc.log = a.self_check_log.as_ref().map(abs);
    }
    if given("mcap") {
        c.sinks.mcap.file = a.mcap.as_ref().map(abs);
    }
    let z = &mut c.bridges.zenoh;
    if a.zenoh || !a.zenoh_connect.is_empty() || a.zenoh_config.is_some() || !a.zenoh_listen.is_empty() {
        z.enabled = true;
    }
    if !a.zenoh_connect.is_empty() {
        z.connect = a.zenoh_connect.clone();
    }
    if !a.zenoh_listen.is_empty() {
        z.listen = a.zenoh_listen.clone();
    }
    z.accept_gaze_goals |= a.zenoh_gaze_goals;
    z.insecure |= a.zenoh_insecure;
    if given("zenoh_config") {
        z.config = a.zenoh_config.as_ref().map(abs);
    }
    if let Some(k) = a.ros2_keys {
        (z.enabled, z.keys) = (true, k);
    }
    z.distro = a.ros_distro.unwrap_or(z.distro);
    if a.no_publish {
        c.bridges.iceoryx.enabled = false;
    }
    if a.no_gaze {
        c.gaze.enabled = false;
    }
    if given("service_prefix") {
        c.bridges.iceoryx.service_prefix = a.service_prefix.clone();
    }
    if let Some(f) = &a.fovea {
        if f == "off" {
            c.fovea.enabled = false;
        } else {
            let (w, h) =
                f.split_once('x').with_context(|| format!("--fovea `{f}`: expected off or WxH, e.g. 320x240"))?;
            c.fovea.enabled = true;
            c.fovea.width = w.parse().with_context(|| format!("--fovea `{f}`: width"))?;
            c.fovea.height = h.parse().with_context(|| format!("--fovea `{f}`: height"))?;
        }
    }
    c.check().map_err(|e| anyhow::anyhow!("configuration: {e}"))?;
    Ok(c)
}
