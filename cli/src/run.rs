//! `abvs run`: the runtime's main job. Replays a recorded session (by default the embedded fixture) through
//! the whole pipeline: time alignment, per-eye FK, moving extrinsic, rectification, disparity, depth and
//! cloud, publishing; prints the latency table and optionally writes the statistics as JSON.
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use abvs_camera::StereoCalibration;
use abvs_runtime::config::{EngineKind, FkSource, RuntimeConfig, SourceKind};
use abvs_runtime::pipeline::{run as run_pipeline, run_replay, PipelineConfig, Sink};
use abvs_runtime::session::Session;
use abvs_runtime::sinks::side_lane::SideLane;
use abvs_runtime::sources::replay::ReplaySource;
use abvs_runtime::tasks::disparity;
use abvs_runtime::tasks::kinematics::{EyeFk, StereoKinematics};
use abvs_runtime::tasks::rectify::RectifiedCamera;
use abvs_sim::truth::TruthSink;
use anyhow::{bail, Context};
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
    #[command(flatten)]
    pub devices: crate::record::DeviceArgs,
    /// Number of frames (at least 1; the session loops when shorter, timestamps kept increasing); default one pass.
    #[arg(long, value_parser = crate::args::count(1u64, u64::MAX))]
    pub frames: Option<u64>,
    /// Loop the session without end: until --seconds (or --frames), or until stopped.
    #[arg(long = "loop")]
    pub looping: bool,
    /// Stop taking frames this many seconds after the start (with --loop: a soak test).
    #[arg(long, value_parser = crate::args::seconds())]
    pub seconds: Option<f64>,
    /// Length of a statistics window in seconds: latency p50/p99, counts and resident memory (RSS) per
    /// window, in the table and the stats JSON (`windows`, `rss`).
    #[arg(long, default_value_t = 60.0, value_parser = crate::args::seconds())]
    pub stats_window: f64,
    /// Write the statistics as JSON.
    #[arg(long)]
    pub stats_json: Option<PathBuf>,
    /// Disparity engine: census-refine (the shipped network refined by a census search: better than SGBM on
    /// real images), onnx (the network alone), sgbm (OpenCV SGBM_3WAY), fused (SGBM where
    /// its checks accept a match, the network elsewhere; costs both).
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
    /// Publish the ROS 2 messages over Zenoh (keys abvs/depth, abvs/camera_info, abvs/points, tf,
    /// abvs/joint_states).
    #[arg(long)]
    pub zenoh: bool,
    /// Zenoh endpoint to connect to, e.g. tcp/192.168.1.20:7447 (repeatable; implies --zenoh).
    #[arg(long, value_name = "ENDPOINT")]
    pub zenoh_connect: Vec<String>,
    /// A standard Zenoh configuration file (JSON5; implies --zenoh).
    #[arg(long, value_name = "FILE")]
    pub zenoh_config: Option<PathBuf>,
    /// Do not publish over iceoryx2.
    #[arg(long)]
    pub no_publish: bool,
    /// iceoryx2 service name prefix (services {prefix}/depth, {prefix}/cloud, with --confidence
    /// {prefix}/confidence).
    #[arg(long, default_value = "abvs")]
    pub service_prefix: String,
    /// Do not print the latency table.
    #[arg(long)]
    pub quiet: bool,
    /// Check the stereo calibration from the rectified images off the critical path: vertical disparity of
    /// matched features and the relative rotation error (stats JSON `self_check`, a warning when it persists).
    #[arg(long)]
    pub self_check: bool,
    /// Rolling-shutter correction: rectify each row with the eye's pose when it exposed (on by default
    /// wherever the frames have a readout; off: one pose per frame, for comparison).
    #[arg(long, value_enum, value_name = "on|off")]
    pub rolling_shutter: Option<OnOff>,
    /// Motion gate (rectified px): frames whose blur (the faster eye's speed x exposure) exceeds this are
    /// published with depth NaN and an empty cloud, flagged in the header [default: 3].
    #[arg(long, value_name = "PX", value_parser = crate::args::positive_up_to(1e9))]
    pub motion_gate_px: Option<f64>,
    /// encoder_time_offset of both eyes (ms; the encoder stream is stamped this much late), overriding the
    /// FK models' (e.g. a timing measured by `abvs calib self-check`, or a wrong one on purpose).
    /// (`--readout-ms` overrides the session's or the cameras' rolling-shutter readout the same way.)
    #[arg(long, value_name = "MS", allow_negative_numbers = true, value_parser = crate::args::finite_in(-1000.0, 1000.0))]
    pub time_offset_ms: Option<f64>,
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
        use crate::outputs::{check_dir_creatable, check_file_writable};
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

/// The checkout's directory of a shipped resource (fixtures/, models/), found next to the executable's
/// checkout or the source tree it was built from.
pub fn shipped(rel: &str) -> PathBuf {
    let mut candidates = Vec::new();
    if let Ok(exe) = std::env::current_exe() {
        for a in exe.ancestors().skip(1).take(4) {
            candidates.push(a.join(rel));
        }
    }
    candidates.push(Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(rel));
    candidates.iter().find(|p| p.exists()).cloned().unwrap_or_else(|| candidates.pop().expect("one candidate"))
}

fn parse_resolution(s: &str) -> anyhow::Result<(u32, u32)> {
    let (w, h) = s.split_once('x').with_context(|| format!("--resolution `{s}`: expected WxH, e.g. 320x240"))?;
    Ok((w.parse().context("--resolution width")?, h.parse().context("--resolution height")?))
}

#[cfg(feature = "rerun")]
fn rerun_sink(p: &Path) -> anyhow::Result<Box<dyn Sink>> {
    Ok(Box::new(abvs_runtime::sinks::rerun_log::RerunSink::create(p)?))
}

#[cfg(not(feature = "rerun"))]
fn rerun_sink(p: &Path) -> anyhow::Result<Box<dyn Sink>> {
    bail!(
        "--rerun {}: this abvs was built without rerun logging; build it with `cargo build --release -p abvs --features rerun`",
        p.display()
    )
}

/// What the pipeline runs on: a recorded session or the live devices.
// One per run: the size of the replay variant does not matter.
#[allow(clippy::large_enum_variant)]
enum Input {
    Replay(Session, PathBuf),
    Live,
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
    if given("width") {
        l.width = d.width;
    }
    if given("height") {
        l.height = d.height;
    }
    if given("fps") {
        l.fps = d.fps;
    }
    if given("fourcc") {
        l.fourcc = d.fourcc.clone();
    }
    if given("exposure_ms") {
        l.exposure_ms = d.exposure_ms;
    }
    if given("readout_ms") {
        // the cameras' readout, and the per-row correction's for a replay as for live
        l.readout_ms = d.readout_ms;
        c.motion.readout_ms = Some(d.readout_ms);
    }
    if let Some(r) = a.rolling_shutter {
        c.motion.rolling_shutter = r == OnOff::On;
    }
    if let Some(px) = a.motion_gate_px {
        c.motion.gate_blur_px = px;
    }
    if given("time_offset_ms") {
        c.motion.time_offset_ms = a.time_offset_ms;
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
    if a.zenoh || !a.zenoh_connect.is_empty() || a.zenoh_config.is_some() {
        z.enabled = true;
    }
    if !a.zenoh_connect.is_empty() {
        z.connect = a.zenoh_connect.clone();
    }
    if given("zenoh_config") {
        z.config = a.zenoh_config.as_ref().map(abs);
    }
    if a.no_publish {
        c.bridges.iceoryx.enabled = false;
    }
    if given("service_prefix") {
        c.bridges.iceoryx.service_prefix = a.service_prefix.clone();
    }
    c.check().map_err(|e| anyhow::anyhow!("configuration: {e}"))?;
    Ok(c)
}

pub fn run(a: RunArgs, m: &ArgMatches) -> anyhow::Result<ExitCode> {
    let c = effective_config(&a, m)?;
    if a.print_config {
        print!("{}", c.to_toml_string());
        return Ok(ExitCode::SUCCESS);
    }
    run_config(&c)
}

/// Frames the truth's side lane holds at most (copies of ~7 MB at 640x480): when scoring falls further
/// behind, a frame goes unscored (counted), the pipeline never waits.
const TRUTH_COPIES: usize = 8;

/// Runs one deployment as its configuration describes it.
pub fn run_config(c: &RuntimeConfig) -> anyhow::Result<ExitCode> {
    check_outputs(c)?;
    let input = match c.source.kind {
        SourceKind::Live => Input::Live,
        SourceKind::Session => {
            let dir = c.source.session.clone().context("source.session")?;
            let session = Session::open(&dir).with_context(|| format!("opening session {}", dir.display()))?;
            Input::Replay(session, dir)
        }
    };
    // calibration: the session's own, or the calibration directory for a live run
    let (stereo_path, fk_paths, gravity) = match &input {
        Input::Replay(session, _) => (
            session.path(&session.meta.stereo),
            [session.path(&session.meta.fk[0]), session.path(&session.meta.fk[1])],
            session.meta.gravity,
        ),
        Input::Live => {
            let c = abvs_runtime::sinks::session_writer::CalibFiles::from_dir(
                c.calibration.dir.as_ref().context("calibration.dir")?,
            );
            c.check()?;
            (c.stereo, c.fk, [0.0, 1.0, 0.0])
        }
    };
    let (w, h) = (c.disparity.width, c.disparity.height);
    let stereo = StereoCalibration::read_yaml(&stereo_path)?;
    let (left, right) = match (c.calibration.fk, &input) {
        (FkSource::Calibrated, _) => (EyeFk::load(&fk_paths[0])?, EyeFk::load(&fk_paths[1])?),
        (FkSource::Nominal, _) => (EyeFk::nominal(), EyeFk::nominal()),
        (FkSource::Truth, Input::Replay(session, _)) => {
            let t = session.meta.truth.as_ref().context("--fk truth needs a synthetic session (with truth/)")?;
            (EyeFk::load(&session.path(&t.units[0]))?, EyeFk::load(&session.path(&t.units[1]))?)
        }
        (FkSource::Truth, Input::Live) => bail!("--fk truth needs a synthetic session, not --live"),
    };
    let mut kin = StereoKinematics::new(left, right, stereo.rotation, stereo.translation_mm / 1000.0);
    kin.gravity = gravity;
    let out = RectifiedCamera::with_hfov(w, h, c.disparity.rect_hfov_deg);
    // disparity range for the eyes' working range at this resolution: f B / z_min
    let max_disp = out.f * stereo.baseline_mm() / 1000.0 / c.disparity.min_depth_m;
    let model = match (&c.disparity.model, c.disparity.engine) {
        (Some(m), _) => Some(m.clone()),
        (None, EngineKind::Onnx | EngineKind::Fused | EngineKind::CensusRefine) => {
            let variant = if w >= 640 { "hitnet-m" } else { "hitnet-s" };
            Some(shipped(&format!("models/hitnet/{variant}")))
        }
        _ => None,
    };
    let engine =
        disparity::engine(c.disparity.engine.as_str(), model.as_deref(), (w, h), max_disp, c.disparity.threads)?;
    let mut sinks: Vec<Box<dyn Sink>> = Vec::new();
    if let (true, Input::Replay(session, _)) = (c.sinks.truth_stride > 0, &input) {
        if let Some(t) = TruthSink::for_session(session, c.sinks.truth_stride)? {
            // scoring costs about a frame's time: beside the pipeline, at idle priority, never in its path
            sinks.push(Box::new(SideLane::new(t, TRUTH_COPIES, c.source.lossless)?));
        }
    }
    if c.bridges.iceoryx.enabled {
        let cfg = abvs_runtime::bridges::iceoryx::BridgeConfig::for_resolution(w, h)
            .with_prefix(c.bridges.iceoryx.service_prefix.clone());
        sinks.push(Box::new(if c.disparity.confidence {
            abvs_runtime::bridges::publish::PublishSink::with_confidence(cfg)?
        } else {
            abvs_runtime::bridges::publish::PublishSink::new(cfg)?
        }));
    }
    // ROS 2 outputs: lossless runs wait for them, live ones drop their oldest queued frame
    if let Some(p) = &c.sinks.mcap.file {
        sinks.push(Box::new(abvs_runtime::sinks::mcap_log::sink(p, c.sinks.mcap.queue, c.source.lossless)?));
    }
    let z = &c.bridges.zenoh;
    if z.enabled {
        sinks.push(Box::new(abvs_runtime::bridges::zenoh::sink(
            z.config.as_deref(),
            &z.connect,
            z.queue,
            c.source.lossless,
        )?));
    }
    if let Some(p) = &c.sinks.rerun {
        sinks.push(rerun_sink(p)?);
    }
    if let Some(d) = &c.sinks.dump {
        sinks.push(Box::new(abvs_runtime::sinks::dump::DumpSink { dir: d.clone(), every: 1 }));
    }
    let sc = &c.sinks.self_check;
    if sc.enabled {
        let cfg = abvs_runtime::sinks::self_check::SelfCheckConfig {
            every: sc.every,
            log: sc.log.clone(),
            threshold_deg: sc.threshold_deg,
            warn_frames: sc.warn_frames,
            // offline and reproducible: every checked frame waits for the worker
            blocking: c.source.lossless,
            ..Default::default()
        };
        sinks.push(Box::new(abvs_runtime::sinks::self_check::SelfCheckSink::new(cfg, &out)?));
    }
    let engine_name = engine.name().to_string();
    let duration = c.source.seconds.map(std::time::Duration::from_secs_f64);
    let window = std::time::Duration::from_secs_f64(c.sinks.stats_window_s);
    let readout_ms;
    let (mut stats, description, source_name) = match input {
        Input::Replay(session, dir) => {
            let description = session.meta.description.clone();
            let mut source = ReplaySource::open(session)?;
            if let Some(r) = c.motion.readout_ms {
                source.set_readout_ns((r * 1e6).round() as i64);
            }
            readout_ms = source.readout_ns() as f64 * 1e-6;
            let cfg = PipelineConfig {
                out,
                motion: c.motion.motion_config(),
                lossless: c.source.lossless,
                paced: c.source.paced && !c.source.lossless,
                // loop without end: as many frames as a u64 counts (with --seconds, until then)
                frames: if c.source.looping { c.source.frames.or(Some(u64::MAX)) } else { c.source.frames },
                duration,
                window,
                check: c.disparity.check_config(),
                // from here Ctrl-C / SIGTERM stop the run cleanly (before it: the default, exit)
                stop: Some(stop_on_signals()?),
                ..Default::default()
            };
            let stats = run_replay(source, kin, (stereo.left, stereo.right), engine, sinks, cfg)?;
            (stats, description, dir.display().to_string())
        }
        Input::Live => {
            let d = &crate::record::DeviceArgs::from(&c.source.live);
            let (capture, encoders) = crate::record::open_devices(d)?;
            wait_for_homing(&encoders, d.homing_timeout)?;
            readout_ms = c.motion.readout_ms.unwrap_or(d.readout_ms);
            let source = abvs_runtime::sources::live::LiveSource::new(capture, encoders, d.width, d.height)
                .with_readout_ns((readout_ms * 1e6).round() as i64);
            // live frames come when the cameras deliver them: never paced
            let cfg = PipelineConfig {
                out,
                motion: c.motion.motion_config(),
                lossless: c.source.lossless,
                paced: false,
                frames: c.source.frames,
                duration,
                window,
                check: c.disparity.check_config(),
                // from here Ctrl-C / SIGTERM stop the run cleanly (before it: the default, exit)
                stop: Some(stop_on_signals()?),
                ..Default::default()
            };
            let stats = run_pipeline(source, kin, (stereo.left, stereo.right), engine, sinks, cfg)?;
            let what = format!("live: {} / {}, encoders {}", d.left.display(), d.right.display(), d.encoders);
            (stats, what.clone(), what)
        }
    };
    stats.extra.insert("session".into(), serde_json::json!(source_name));
    stats.extra.insert("engine".into(), serde_json::json!(engine_name));
    stats.extra.insert("fk".into(), serde_json::json!(c.calibration.fk));
    stats.extra.insert("resolution".into(), serde_json::json!([w, h]));
    stats.extra.insert(
        "motion".into(),
        serde_json::json!({
            "readout_ms": readout_ms,
            "rolling_shutter": c.motion.rolling_shutter && readout_ms > 0.0,
            "row_bands": c.motion.row_bands,
            "gate_blur_px": c.motion.gate_blur_px,
            "time_offset_ms": c.motion.time_offset_ms,
        }),
    );
    let elapsed = stats.extra.get("elapsed_s").and_then(|v| v.as_f64()).unwrap_or(0.0);
    if !c.sinks.quiet {
        println!("session {source_name} ({description})");
        let d = &c.disparity;
        let check = match (d.confidence, d.lr_check) {
            (false, false) => String::new(),
            (conf, lr) => format!(
                ", left-right check ({}{}{}, {} px)",
                if conf { "confidence" } else { "" },
                if conf && lr { " + " } else { "" },
                if lr { "inconsistent pixels dropped" } else { "" },
                d.lr_max_diff
            ),
        };
        println!("engine {engine_name} at {w}x{h}{check}, fk {}", c.calibration.fk.as_str());
        print!("{}", stats.table(elapsed));
        if let Some(v) = stats.extra.get("truth_side_lane") {
            let n = |f: &str| v[f].as_u64().unwrap_or(0);
            println!(
                "depth error scored on {} of {} published frames (side lane at idle priority: {} skipped, {} \
                 scored after the run)",
                n("frames_consumed"),
                n("frames_in"),
                n("frames_skipped"),
                n("drained_at_finish")
            );
        }
        if let Some(v) = stats.extra.get("self_check") {
            println!("{}", abvs_runtime::sinks::self_check::summary_line(v));
        }
        if let Some(v) = stats.extra.get("depth_error_by_confidence") {
            let part = |p: &serde_json::Value| {
                format!(
                    "abs rel {:.2} %, rmse {:.1} mm ({} points)",
                    p["abs_rel"].as_f64().unwrap_or(f64::NAN) * 100.0,
                    p["rmse_m"].as_f64().unwrap_or(f64::NAN) * 1000.0,
                    p["points"].as_u64().unwrap_or(0)
                )
            };
            let t = v["threshold"].as_f64().unwrap_or(f64::NAN);
            println!(
                "depth error vs truth by confidence: > {t:.1}: {}; <= {t:.1}: {}",
                part(&v["above"]),
                part(&v["at_most"])
            );
        }
        if let Some(serde_json::Value::Array(bands)) = stats.extra.get("depth_error_by_speed") {
            println!("depth error vs truth by eye speed (deg/s): frames scored / gated, abs rel, point error p50");
            for b in bands.iter().filter(|b| b["frames"].as_u64().unwrap_or(0) + b["gated"].as_u64().unwrap_or(0) > 0) {
                let hi = b["deg_s"][1].as_f64().map_or("inf".to_string(), |h| format!("{h:.0}"));
                println!(
                    "  [{:>3.0}, {hi:>3}): {:>3} / {:>3}  {:>6.2} %  {:>6.1} mm",
                    b["deg_s"][0].as_f64().unwrap_or(0.0),
                    b["frames"].as_u64().unwrap_or(0),
                    b["gated"].as_u64().unwrap_or(0),
                    b["abs_rel"].as_f64().unwrap_or(f64::NAN) * 100.0,
                    b["point_mm_p50"].as_f64().unwrap_or(f64::NAN)
                );
            }
        }
        for k in ["zenoh", "mcap"] {
            if let Some(v) = stats.extra.get(k) {
                let n = |f: &str| v[f].as_u64().unwrap_or(0);
                let err = v["last_error"].as_str().map(|e| format!(", first error: {e}")).unwrap_or_default();
                println!(
                    "{k}: {} of {} frames written, {} dropped (queue full), {} failed{err}",
                    n("frames_written"),
                    n("frames_in"),
                    n("frames_dropped"),
                    n("frames_failed")
                );
            }
        }
    }
    if let Some(p) = &c.sinks.stats_json {
        std::fs::write(p, serde_json::to_string_pretty(&stats.json(elapsed))? + "\n")
            .with_context(|| format!("writing {}", p.display()))?;
    }
    Ok(ExitCode::SUCCESS)
}

/// The configuration's output files before the run (a soak must not lose its statistics at the end).
fn check_outputs(c: &RuntimeConfig) -> anyhow::Result<()> {
    use crate::outputs::{check_dir_creatable, check_file_writable};
    let s = &c.sinks;
    for (field, p) in [
        ("sinks.stats_json", &s.stats_json),
        ("sinks.self_check.log", &s.self_check.log),
        ("sinks.mcap.file", &s.mcap.file),
        ("sinks.rerun", &s.rerun),
    ] {
        if let Some(p) = p {
            check_file_writable(field, p)?;
        }
    }
    match &s.dump {
        Some(d) => check_dir_creatable("sinks.dump", d),
        None => Ok(()),
    }
}

/// A flag set by Ctrl-C (SIGINT) or SIGTERM: the run stops taking frames, finishes those in flight and
/// reports (table, stats JSON) as at its end; a second signal exits at once (status 1).
fn stop_on_signals() -> anyhow::Result<&'static std::sync::atomic::AtomicBool> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    let flag: &'static std::sync::Arc<std::sync::atomic::AtomicBool> = Box::leak(Box::default());
    for sig in [SIGINT, SIGTERM] {
        signal_hook::flag::register_conditional_shutdown(sig, 1, flag.clone())
            .context("installing a signal handler")?;
        signal_hook::flag::register(sig, flag.clone()).context("installing a signal handler")?;
    }
    Ok(&**flag)
}

/// Waits until the drive board's stream has homed both eyes (their links roll through the index
/// markers at start-up), or fails naming the eye and the last refusal.
fn wait_for_homing(
    encoders: &abvs_runtime::sources::encoder_stream::EncoderStream,
    timeout_s: f64,
) -> anyhow::Result<()> {
    let t0 = std::time::Instant::now();
    while encoders.homed() != [true, true] {
        if encoders.is_finished() {
            bail!("the encoder stream ended before homing");
        }
        if t0.elapsed().as_secs_f64() > timeout_s {
            let s = encoders.stats();
            bail!(
                "eyes not homed within {timeout_s:.0} s (homed {:?}; samples {:?}; last refusals {:?})",
                encoders.homed(),
                s.homing_samples,
                s.last_homing_error
            );
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    Ok(())
}
