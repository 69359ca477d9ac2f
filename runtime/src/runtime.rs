//! One call from a configuration to a running runtime.
//!
//! [`Runtime::from_config`] does everything a deployment's configuration ([`RuntimeConfig`]) says: opens the
//! source (a recorded session, or the eye cameras and the drive board, homed), loads the stereo calibration and
//! the FK models, builds the disparity engine, and opens the sinks and bridges. [`Runtime::add_sink`] adds the
//! caller's own sinks; [`Runtime::run`], [`Runtime::run_until`] or [`Runtime::spawn`] then run the standard graph
//! ([`crate::pipeline`]) and return its [`Report`]. The `abvs run` program is this call plus its flags.
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use abvs_camera::{Camera, StereoCalibration};

use crate::bridges::publish::PublishSink;
use crate::gaze::controller::GazeController;
use crate::gaze::stage::GazeStage;
use crate::gaze::{GazeConfig, GazeHandle, Mailbox};
use crate::pipeline::PipelineConfig;
use crate::runner::{Counts, Progress};
use crate::sinks::self_check::TimingContext;
use crate::sinks::session_writer::CalibFiles;
use crate::sources::live::LiveSource;
use crate::sources::replay::ReplaySource;
use crate::tasks::disparity::runtime_error;
use crate::tasks::kinematics::{EyeFk, StereoKinematics};
use crate::tasks::rectify::camera_for_frames;
use abvs_disparity::engine::DisparityEngine;
use abvs_runtime_core::config::{EngineKind, FkSource, RuntimeConfig, SourceKind};
use abvs_runtime_core::error::{Result, RuntimeError};
use abvs_runtime_core::messages::RectifiedCamera;
use abvs_runtime_core::session::Session;
use abvs_runtime_core::sink::Sink;
use abvs_runtime_core::stats::RunStats;

/// Where the frames come from.
// One per runtime: the size of the replay variant does not matter.
#[allow(clippy::large_enum_variant)]
enum Input {
    Replay(ReplaySource),
    Live(LiveSource),
    /// A source the caller built ([`Runtime::with_source`]).
    Custom(Box<dyn abvs_runtime_core::source::PairSource>),
}

/// A source built outside the runtime (the toolkit's simulated head, `source.kind = "sim"`), for
/// [`Runtime::with_source`].
pub struct CustomSource {
    /// The frames, encoders and board.
    pub source: Box<dyn abvs_runtime_core::source::PairSource>,
    /// The rolling-shutter readout its frames carry (ms).
    pub readout_ms: f64,
    /// What the report calls it.
    pub name: String,
}

/// A deployment, assembled and ready to run: source, calibration, engine, sinks and bridges.
pub struct Runtime {
    config: RuntimeConfig,
    input: Input,
    kin: StereoKinematics,
    cams: (Camera, Camera),
    engine: Box<dyn DisparityEngine>,
    out: RectifiedCamera,
    sinks: Vec<Box<dyn Sink>>,
    /// The rolling-shutter readout the frames carry (ms).
    readout_ms: f64,
    /// The motion settings the stages run with (the time offset resolved: configuration, session, FK models).
    motion: abvs_runtime_core::params::MotionConfig,
    source_name: String,
    description: String,
    /// The gaze goals' mailbox ([`Runtime::gaze`]) and both eyes' IK models.
    gaze: Arc<Mailbox>,
    gaze_models: [abvs_fk::model::FkModel; 2],
    /// Where gaze goals are taken from (the start-up line, [`Runtime::gaze_access`]).
    gaze_access: String,
}

/// What a finished run reports.
pub struct Report {
    /// Counts, latencies, the output digest, and what each stage and sink added (`extra`).
    pub stats: RunStats,
    /// Seconds the run took, from its start to its last frame.
    pub elapsed_s: f64,
    /// The session directory, or the live devices.
    pub source: String,
    /// The session's description, or the live devices.
    pub description: String,
    /// The disparity engine's name.
    pub engine: String,
}

impl Report {
    /// The statistics as JSON (what `sinks.stats_json` writes).
    pub fn json(&self) -> serde_json::Value {
        self.stats.json(self.elapsed_s)
    }

    /// The latency table (what `abvs run` prints).
    pub fn table(&self) -> String {
        self.stats.table(self.elapsed_s)
    }

    /// Whether the run dropped frames because the computer could not do a frame's work in a frame period.
    pub fn overload(&self) -> Option<Overload> {
        overload(&self.stats.cpu_json(self.elapsed_s)?, self.stats.frames_dropped)
    }
}

/// Share of the cores a run kept busy (idle priority aside) above which dropped frames mean the computer is
/// short of CPU, not that a frame met a passing hiccup. Lanes that hand frames to each other cannot use
/// every cycle: the default at 640x480 dropped 11-22 of 125 frames at 1.73-1.8 of 2 cores on this project's
/// 2-core VM (2026-11-26), census-refine on hitnet-s none at 1.2.
pub const SATURATED: f64 = 0.8;

/// A run that dropped frames with the cores busy: the computer is short of CPU for its setting.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Overload {
    /// Frames dropped.
    pub dropped: u64,
    /// Cores kept busy, the idle-priority side lanes aside.
    pub cores_busy: f64,
    /// Cores of the computer.
    pub cores: f64,
    /// CPU per frame, all threads (ms).
    pub ms_per_frame: f64,
}

impl Overload {
    /// The lighter settings for `engine` (the report's engine name), as command-line advice.
    pub fn lighter(engine: &str) -> &'static str {
        if engine.starts_with("census-refine") && !engine.starts_with("census-refine:hitnet-s") {
            "no `--model` (the default: hitnet-s and SGBM at 320x240, about half the disparity stage's CPU) or \
             `--resolution 320x240`"
        } else {
            "`--resolution 320x240`"
        }
    }
}

/// [`Report::overload`] from the stats JSON's `cpu` and the frames dropped: `None` unless frames were dropped
/// with at least [`SATURATED`] of the cores busy.
pub fn overload(cpu: &serde_json::Value, dropped: u64) -> Option<Overload> {
    // the idle-priority side lanes only fill what the pipeline leaves: not a shortage
    let busy = cpu["cores_busy_without_idle_priority"].as_f64()?;
    let cores = cpu["cores"].as_u64()? as f64;
    if dropped == 0 || busy < SATURATED * cores {
        return None;
    }
    let ms_per_frame = cpu["ms_per_frame"].as_f64().unwrap_or(f64::NAN);
    Some(Overload { dropped, cores_busy: busy, cores, ms_per_frame })
}

impl Runtime {
    /// Assembles the deployment `config` describes. Everything that can be checked is checked here, before any
    /// frame: the configuration's values, its output paths, the calibration and model files, the engine, the
    /// bridges' shared memory; a live source's devices are opened last and the eyes homed.
    pub fn from_config(config: &RuntimeConfig) -> Result<Runtime> {
        Self::assemble(config, None)
    }

    /// A deployment whose frames, encoders and drive board come from `source` (`source.kind = "sim"`: the
    /// toolkit's simulated head, which runs in virtual time, so the run is lossless and never paced); the
    /// calibration is `calibration.dir`'s, as for a live run.
    pub fn with_source(config: &RuntimeConfig, source: CustomSource) -> Result<Runtime> {
        if config.calibration.dir.is_none() {
            return Err(RuntimeError::Config("calibration.dir: a custom source needs one".into()));
        }
        let mut c = config.clone();
        c.source.lossless = true;
        Self::assemble(&c, Some(source))
    }

    fn assemble(config: &RuntimeConfig, custom: Option<CustomSource>) -> Result<Runtime> {
        let c = config;
        c.check().map_err(RuntimeError::Config)?;
        check_outputs(c)?;
        let session = match (c.source.kind, &custom) {
            (_, Some(_)) => None,
            (SourceKind::Session, None) => {
                let dir = c.source.session.as_deref().expect("checked: kind = session has a session");
                Some(Session::open(dir)?)
            }
            (SourceKind::Live, None) => None,
            (SourceKind::Sim, None) => {
                return Err(RuntimeError::Invalid(
                    "source.kind = \"sim\": the simulated head is the toolkit's (`abvs run --source sim`); a \
                     program builds its source and calls Runtime::with_source"
                        .into(),
                ))
            }
        };
        let (stereo, kin) = calibration(c, session.as_ref())?;
        let gaze_models = [kin.left.ik_model()?, kin.right.ik_model()?];
        let gaze = Arc::new(Mailbox::default());
        let out = RectifiedCamera::with_hfov(c.disparity.width, c.disparity.height, c.disparity.rect_hfov_deg);
        let engine = engine(c, &out, &stereo)?;
        // encoder_time_offset: the configuration's, else the session's measured one, else the FK models'
        let mut motion = c.motion.motion_config();
        if motion.time_offset_s.is_none() {
            let measured = session.as_ref().and_then(|s| s.meta.time_offset_ms);
            motion.time_offset_s = measured.map(|t| t.per_eye().map(|t| t * 1e-3));
        }
        let offsets_s = motion.time_offset_s.unwrap_or_else(|| kin.encoder_latency_s());
        let (fw, fh) = match (&session, &custom) {
            (Some(s), _) => (s.meta.width, s.meta.height),
            (None, Some(s)) => s.source.size(),
            (None, None) => (c.source.live.width, c.source.live.height),
        };
        check_readout(c, session.as_ref())?;
        // the self-check's timing evidence needs the raw cameras at the frames' size (a size the calibration
        // does not fit is refused by the rectify stage, by name)
        let timing = match (camera_for_frames(&stereo.left, fw, fh), camera_for_frames(&stereo.right, fw, fh)) {
            (Ok(l), Ok(r)) => Some(TimingContext { cams: [l, r], time_offset_ms: offsets_s.map(|t| t * 1e3) }),
            _ => None,
        };
        let (sinks, gaze_access) = sinks(c, &out, timing, &gaze)?;
        let (input, readout_ms, source_name, description) = match (session, custom) {
            (_, Some(s)) => (Input::Custom(s.source), s.readout_ms, s.name.clone(), s.name),
            (Some(session), None) => {
                let (name, description) = (session.dir.display().to_string(), session.meta.description.clone());
                let mut source = ReplaySource::open(session)?;
                if let Some(r) = c.motion.readout_ms {
                    source.set_readout_ns((r * 1e6).round() as i64);
                }
                let readout_ms = source.readout_ns() as f64 * 1e-6;
                (Input::Replay(source), readout_ms, name, description)
            }
            (None, None) => {
                let l = &c.source.live;
                let readout_ms = c.motion.readout_ms.unwrap_or(l.readout_ms);
                let source = LiveSource::open(l)?.with_readout_ns((readout_ms * 1e6).round() as i64);
                let what = format!("live: {} / {}, encoders {}", l.left.display(), l.right.display(), l.encoders);
                (Input::Live(source), readout_ms, what.clone(), what)
            }
        };
        Ok(Runtime {
            config: c.clone(),
            input,
            kin,
            cams: (stereo.left, stereo.right),
            engine,
            out,
            sinks,
            readout_ms,
            motion,
            source_name,
            description,
            gaze,
            gaze_models,
            gaze_access,
        })
    }

    /// Points the eyes of this runtime once it runs (goals are taken from its first frame; without a drive
    /// board, a replay, they are refused with `no_board`; with `[gaze] enabled = false` none is taken and
    /// [`GazeHandle::state`] stays `None`).
    pub fn gaze(&self) -> GazeHandle {
        GazeHandle::new(self.gaze.clone())
    }

    /// Where the runtime takes gaze goals from: this machine only (iceoryx2, the Rust handle), or also the
    /// network over Zenoh and how it is secured (the line `abvs run` prints at start-up).
    pub fn gaze_access(&self) -> &str {
        &self.gaze_access
    }

    /// Adds a sink of the caller's: it receives every published frame ([`abvs_runtime_core::messages::Published`]: depth,
    /// cloud, poses, the rectified pair) on the output lane, after the sinks and bridges of the configuration.
    /// Its [`Sink::consume`] runs on the pipeline's critical path: it must not block, and should not allocate.
    pub fn add_sink(&mut self, sink: Box<dyn Sink>) {
        self.sinks.push(sink);
    }

    /// The configuration this runtime was assembled from.
    pub fn config(&self) -> &RuntimeConfig {
        &self.config
    }

    /// The recorded session being replayed (`None` live): e.g. for a sink that scores against its ground truth.
    pub fn replay(&self) -> Option<&ReplaySource> {
        match &self.input {
            Input::Replay(r) => Some(r),
            Input::Live(_) | Input::Custom(_) => None,
        }
    }

    /// The disparity engine's name.
    pub fn engine_name(&self) -> &str {
        self.engine.name()
    }

    /// The rectified output camera every frame's depth is in.
    pub fn output_camera(&self) -> RectifiedCamera {
        self.out
    }

    /// Runs to the end of the source (a session's frames, `source.frames`, `source.seconds`).
    pub fn run(self) -> Result<Report> {
        self.run_with(None, None)
    }

    /// Runs until the source ends or `stop` is set (e.g. by a signal handler): then it takes no more frames,
    /// finishes those in flight and reports as at the end.
    pub fn run_until(self, stop: Arc<AtomicBool>) -> Result<Report> {
        self.run_with(Some(stop), None)
    }

    /// Runs on a thread of its own; the handle stops it, reads its counts while it runs, and joins it.
    pub fn spawn(self) -> Result<RuntimeHandle> {
        let stop = Arc::new(AtomicBool::new(false));
        let progress = Arc::new(Progress::default());
        let (s, p) = (stop.clone(), progress.clone());
        let gaze = self.gaze();
        let thread = std::thread::Builder::new()
            .name("abvs-runtime".into())
            .spawn(move || self.run_with(Some(s), Some(p)))
            .map_err(|source| RuntimeError::Thread { what: "starting the runtime's thread".into(), source })?;
        Ok(RuntimeHandle { stop, progress, gaze, thread: Some(thread) })
    }

    fn run_with(self, stop: Option<Arc<AtomicBool>>, progress: Option<Arc<Progress>>) -> Result<Report> {
        let Runtime {
            config: c,
            input,
            kin,
            cams,
            engine,
            out,
            sinks,
            readout_ms,
            motion,
            source_name,
            description,
            gaze,
            gaze_models,
            gaze_access: _,
        } = self;
        let ctl = GazeController::new(GazeConfig::default(), gaze_models, &kin.home_left_to_right, kin.gravity);
        // off: the standard graph, without the gaze stage (the depth is the same as on without goals)
        let gaze = c
            .gaze
            .enabled
            .then(|| GazeStage::new(ctl, gaze, kin.home_left_to_right).with_rate_limit(c.gaze.rate_limit()));
        let engine_name = engine.name().to_string();
        let replay = matches!(input, Input::Replay(_));
        let custom = matches!(input, Input::Custom(_));
        // live frames come when the cameras deliver them: never paced
        let paced = replay && c.source.paced && !c.source.lossless;
        let cfg = PipelineConfig {
            out,
            motion,
            lossless: c.source.lossless,
            paced,
            // a replay loops without end as many frames as a u64 counts (with `seconds`, until then)
            frames: if replay && c.source.looping { c.source.frames.or(Some(u64::MAX)) } else { c.source.frames },
            duration: c.source.seconds.map(Duration::from_secs_f64),
            window: Duration::from_secs_f64(c.sinks.stats_window_s),
            check: c.disparity.check_config(),
            min_confidence: c.disparity.min_confidence as f32,
            fovea: c.fovea.fovea_config(),
            stop,
            progress,
            ..Default::default()
        };
        let mut stats = match input {
            Input::Replay(s) => crate::pipeline::run_with_gaze(s, kin, cams, engine, sinks, cfg, gaze)?,
            Input::Live(s) => crate::pipeline::run_with_gaze(s, kin, cams, engine, sinks, cfg, gaze)?,
            Input::Custom(s) => crate::pipeline::run_with_gaze(s, kin, cams, engine, sinks, cfg, gaze)?,
        };
        // an unpaced replay takes frames ahead of their times: no latency to report
        // (a custom source, the simulated head, runs in virtual time: its latency is not the computer's)
        stats.latency_measured = (!replay && !custom) || paced;
        let (w, h) = (c.disparity.width, c.disparity.height);
        let extra = &mut stats.extra;
        extra.insert("session".into(), serde_json::json!(source_name));
        extra.insert("engine".into(), serde_json::json!(&engine_name));
        extra.insert("fk".into(), serde_json::json!(c.calibration.fk));
        extra.insert("resolution".into(), serde_json::json!([w, h]));
        extra.insert(
            "motion".into(),
            serde_json::json!({
                "readout_ms": readout_ms,
                "rolling_shutter": c.motion.rolling_shutter && readout_ms > 0.0,
                "row_bands": c.motion.row_bands,
                "gate_blur_px": c.motion.gate_blur_px,
                "time_offset_ms": motion.time_offset_s.map(|t| t.map(|t| t * 1e3)),
            }),
        );
        let elapsed_s = stats.extra.get("elapsed_s").and_then(|v| v.as_f64()).unwrap_or(0.0);
        let report = Report { stats, elapsed_s, source: source_name, description, engine: engine_name };
        if let Some(p) = &c.sinks.stats_json {
            let text = serde_json::to_string_pretty(&report.json()).expect("statistics serialise") + "\n";
            std::fs::write(p, text).map_err(|e| RuntimeError::File {
                path: p.clone(),
                line: None,
                msg: format!("writing: {e}"),
            })?;
        }
        Ok(report)
    }
}

/// A runtime running on its own thread ([`Runtime::spawn`]). Dropping the handle stops the run and waits for
/// it.
pub struct RuntimeHandle {
    stop: Arc<AtomicBool>,
    progress: Arc<Progress>,
    gaze: GazeHandle,
    thread: Option<JoinHandle<Result<Report>>>,
}

impl RuntimeHandle {
    /// Asks the run to stop: it takes no more frames and finishes those in flight.
    pub fn stop(&self) {
        self.stop.store(true, Ordering::Relaxed);
    }

    /// Points the running eyes: look at a point, pursue one, hold, go home ([`GazeHandle`]).
    pub fn gaze(&self) -> GazeHandle {
        self.gaze.clone()
    }

    /// Frames taken, published and dropped so far.
    pub fn stats(&self) -> Counts {
        self.progress.counts()
    }

    /// Whether the run has ended (its source ended, or it was stopped, or it failed).
    pub fn is_finished(&self) -> bool {
        self.thread.as_ref().is_none_or(|t| t.is_finished())
    }

    /// Waits for the end of the run and returns its report.
    pub fn join(mut self) -> Result<Report> {
        let t = self.thread.take().expect("joined once");
        t.join().map_err(|_| RuntimeError::Panicked("the runtime's thread".into()))?
    }
}

impl Drop for RuntimeHandle {
    fn drop(&mut self) {
        if let Some(t) = self.thread.take() {
            self.stop();
            let _ = t.join();
        }
    }
}

/// The stereo calibration and both eyes' kinematics (FK as `calibration.fk` says): the session's own, or the
/// calibration directory's for a live run.
fn calibration(c: &RuntimeConfig, session: Option<&Session>) -> Result<(StereoCalibration, StereoKinematics)> {
    let (stereo_path, fk_paths, gravity) = match session {
        Some(s) => (s.path(&s.meta.stereo), [s.path(&s.meta.fk[0]), s.path(&s.meta.fk[1])], s.meta.gravity),
        None => {
            let files = CalibFiles::from_dir(c.calibration.dir.as_deref().expect("checked: live runs have one"));
            // every file loads before a device is opened
            files.check()?;
            (files.stereo, files.fk, [0.0, 1.0, 0.0])
        }
    };
    let stereo = StereoCalibration::read_yaml(&stereo_path)
        .map_err(|e| RuntimeError::Model { path: stereo_path.clone(), msg: e.to_string() })?;
    let (left, right) = match (c.calibration.fk, session) {
        (FkSource::Calibrated, _) => (EyeFk::load(&fk_paths[0])?, EyeFk::load(&fk_paths[1])?),
        (FkSource::Nominal, _) => (EyeFk::nominal(), EyeFk::nominal()),
        (FkSource::Truth, Some(s)) => {
            let t = s.meta.truth.as_ref().ok_or_else(|| {
                RuntimeError::Invalid("calibration.fk = truth needs a synthetic session (with truth/)".into())
            })?;
            (EyeFk::load(&s.path(&t.units[0]))?, EyeFk::load(&s.path(&t.units[1]))?)
        }
        (FkSource::Truth, None) => {
            return Err(RuntimeError::Invalid("calibration.fk = truth needs a synthetic session, not live".into()))
        }
    };
    let mut kin = StereoKinematics::new(left, right, stereo.rotation, stereo.translation_mm / 1000.0);
    kin.gravity = gravity;
    Ok((stereo, kin))
}

/// The disparity engine `disparity` names, its range set for the eyes' working range: f B / z_min.
fn engine(c: &RuntimeConfig, out: &RectifiedCamera, stereo: &StereoCalibration) -> Result<Box<dyn DisparityEngine>> {
    let d = &c.disparity;
    let max_disp = out.f * stereo.baseline_mm() / 1000.0 / d.min_depth_m;
    let model = match (&d.model, d.engine) {
        (Some(m), _) => Some(m.clone()),
        (None, EngineKind::Onnx | EngineKind::Fused | EngineKind::CensusRefine) => {
            Some(abvs_disparity::manifest::default_model_for(d.width, d.height))
        }
        (None, EngineKind::Sgbm) => None,
    };
    abvs_disparity::factory::engine(d.engine.as_str(), model.as_deref(), (d.width, d.height), max_disp, d.threads)
        .map_err(runtime_error)
}

/// The sinks and bridges the configuration names, in the order they run on the output lane.
fn sinks(
    c: &RuntimeConfig,
    out: &RectifiedCamera,
    timing: Option<TimingContext>,
    gaze: &Arc<Mailbox>,
) -> Result<(Vec<Box<dyn Sink>>, String)> {
    let mut sinks: Vec<Box<dyn Sink>> = Vec::new();
    if c.bridges.iceoryx.enabled {
        let cfg = crate::bridges::iceoryx::BridgeConfig::for_deployment(c);
        // the publishers first: their nodes remove (and count) what a killed runtime left behind
        let publish = if computes_confidence(c) {
            PublishSink::with_confidence(cfg.clone())?
        } else {
            PublishSink::new(cfg.clone())?
        };
        sinks.push(Box::new(match c.fovea.fovea_config() {
            Some(f) => publish.with_fovea(f.width, f.height)?,
            None => publish,
        }));
        // gaze goals in, the state of every frame out (`{prefix}/gaze/goal`, `{prefix}/gaze/state`)
        if c.gaze.enabled {
            sinks.push(Box::new(
                crate::bridges::iceoryx::gaze::GazeBridge::new(&cfg, gaze.clone())
                    .map_err(|e| RuntimeError::Ipc(Box::new(e)))?,
            ));
        }
    }
    // ROS 2 outputs: lossless runs wait for them, live ones drop their oldest queued frame
    if let Some(p) = &c.sinks.mcap.file {
        sinks.push(mcap_sink(p, c)?);
    }
    let access = zenoh_sinks(c, gaze, &mut sinks)?;
    if let Some(p) = &c.sinks.rerun {
        sinks.push(rerun_sink(p)?);
    }
    if let Some(d) = &c.sinks.dump {
        sinks.push(Box::new(crate::sinks::dump::DumpSink { dir: d.clone(), every: 1 }));
    }
    let sc = &c.sinks.self_check;
    if sc.enabled {
        let toml = c.to_toml_string();
        let mut cfg = abvs_runtime_core::params::SelfCheckConfig {
            every: sc.every,
            log: sc.log.clone(),
            threshold_deg: sc.threshold_deg,
            warn_frames: sc.warn_frames,
            // offline and reproducible: every checked frame waits for the worker
            blocking: c.source.lossless,
            ..Default::default()
        };
        if let Some(log) = &sc.log {
            // the run's configuration beside its log: an offline estimate can replay it with other timing; the
            // run's identity in both, so that a log is never fitted or replayed with another run's
            cfg.run_id = crate::sinks::self_check::new_run_id(&toml);
            let p = crate::sinks::self_check::log_record::run_config_path(log);
            // the replayed session's session.toml as read now, so that a replay of another session shows
            let session_toml = match (c.source.kind, &c.source.session) {
                (abvs_runtime_core::config::SourceKind::Session, Some(d)) => {
                    std::fs::read(d.join(abvs_runtime_core::session::SESSION_FILE)).ok()
                }
                _ => None,
            };
            let text =
                crate::sinks::self_check::log_record::run_config_text(cfg.run_id, &toml, session_toml.as_deref());
            std::fs::write(&p, text).map_err(|e| RuntimeError::File {
                path: p.clone(),
                line: None,
                msg: format!("writing: {e}"),
            })?;
        }
        sinks.push(Box::new(crate::sinks::self_check::SelfCheckSink::with_timing(cfg, out, timing)?));
    }
    Ok((sinks, access))
}

/// Whether the run computes a confidence: then it is published (iceoryx2 and ROS 2) by default.
fn computes_confidence(c: &RuntimeConfig) -> bool {
    c.disparity.confidence || c.disparity.engine.scores_pixels()
}

/// The ROS 2 outputs' optional topics: the fovea's and the confidence when the run computes them.
#[cfg(any(feature = "zenoh", feature = "mcap"))]
fn topic_set(c: &RuntimeConfig) -> crate::ros2::TopicSet {
    crate::ros2::TopicSet { fovea: c.fovea.fovea_config().is_some(), confidence: computes_confidence(c) }
}

/// The start-up line's gaze access with `[gaze] enabled = false`.
const GAZE_OFF: &str = "gaze: off ([gaze] enabled = false): no goals are taken, no gaze state is published";

/// The MCAP recorder of `[sinks.mcap]` (cargo feature `mcap`).
#[cfg(feature = "mcap")]
fn mcap_sink(p: &Path, c: &RuntimeConfig) -> Result<Box<dyn Sink>> {
    Ok(Box::new(crate::sinks::mcap_log::sink(p, c.sinks.mcap.queue, c.source.lossless, topic_set(c))?))
}

/// Built without MCAP: a configuration that asks for a recording is refused.
#[cfg(not(feature = "mcap"))]
fn mcap_sink(_: &Path, _: &RuntimeConfig) -> Result<Box<dyn Sink>> {
    Err(RuntimeError::NotBuilt { field: "sinks.mcap.file", feature: "mcap" })
}

/// The Zenoh outputs and gaze topics of `[bridges.zenoh]` (cargo feature `zenoh`); returns where gaze goals are
/// taken from, for the start-up line.
#[cfg(feature = "zenoh")]
fn zenoh_sinks(c: &RuntimeConfig, gaze: &Arc<Mailbox>, sinks: &mut Vec<Box<dyn Sink>>) -> Result<String> {
    use ::zenoh::Wait;
    let z = &c.bridges.zenoh;
    let zc = crate::bridges::zenoh_gaze::config(z)?;
    // checked before any session opens: goals over the network need authentication or access control
    let access = if c.gaze.enabled {
        crate::bridges::zenoh_gaze::goal_access(z, &zc, c.bridges.iceoryx.enabled)?
    } else {
        GAZE_OFF.to_string()
    };
    if z.enabled || z.accept_gaze_goals {
        // one session (one peer, one identity for the access control) for the outputs and the gaze topics
        let session = ::zenoh::open(zc)
            .wait()
            .map_err(|source| RuntimeError::Transport { what: "zenoh: opening the session".into(), source })?;
        // the gaze topics first: they finish before the outputs close the session
        if c.gaze.enabled {
            let g = crate::bridges::zenoh_gaze::ZenohGaze::new(session.clone(), z, gaze.clone(), z.enabled)?;
            sinks.push(Box::new(g));
        }
        if z.enabled {
            let w = crate::bridges::zenoh::ZenohWriter::on_session(session, z, topic_set(c))?;
            sinks.push(Box::new(crate::sinks::ros2_out::Ros2OutSink::new("zenoh", w, z.queue, c.source.lossless)?));
        }
    }
    Ok(access)
}

/// Built without Zenoh: a configuration that turns it on is refused; goals come from this machine only.
#[cfg(not(feature = "zenoh"))]
fn zenoh_sinks(c: &RuntimeConfig, _: &Arc<Mailbox>, _: &mut Vec<Box<dyn Sink>>) -> Result<String> {
    let z = &c.bridges.zenoh;
    if z.enabled || z.accept_gaze_goals {
        let field = if z.enabled { "bridges.zenoh.enabled" } else { "bridges.zenoh.accept_gaze_goals" };
        return Err(RuntimeError::NotBuilt { field, feature: "zenoh" });
    }
    if !c.gaze.enabled {
        return Ok(GAZE_OFF.to_string());
    }
    let local = if c.bridges.iceoryx.enabled {
        "this machine (iceoryx2 `gaze/goal`, the Rust handle)"
    } else {
        "this process (the Rust handle; iceoryx2 off)"
    };
    Ok(format!("gaze goals from {local}; over Zenoh: not built (cargo feature `zenoh`)"))
}

/// A rolling-shutter readout is at most one frame period (the sensor reads the next frame's first row after
/// this frame's last), and so is a live camera's exposure: checked against the frames it applies to, the session's rate in a replay, the cameras'
/// live, before any sink writes a file. Names where the value came from.
fn check_readout(c: &RuntimeConfig, session: Option<&Session>) -> Result<()> {
    let (fps, rate_from) = match session {
        Some(s) => (s.meta.fps, format!("the session's {} fps", s.meta.fps)),
        None => (c.source.live.fps as f64, format!("[source.live] fps = {}", c.source.live.fps)),
    };
    let period_ms = 1000.0 / fps;
    let (r, from) = match (c.motion.readout_ms, session) {
        (Some(r), _) => (r, "[motion] readout_ms (--readout-ms)"),
        (None, Some(_)) => return Ok(()), // session.toml's own readout is checked when the session opens
        (None, None) => (c.source.live.readout_ms, "[source.live] readout_ms (--readout-ms)"),
    };
    if !(0.0..=period_ms).contains(&r) {
        return Err(RuntimeError::Invalid(format!(
            "{from}: {r} ms is out of range (0 ..= {period_ms:.3} ms, one frame period at {rate_from})"
        )));
    }
    // the cameras' exposure, live: a row exposes within its frame period (a replay's is its session.toml's)
    if let (None, abvs_runtime_core::config::SourceKind::Live, Some(e)) =
        (session, c.source.kind, c.source.live.exposure_ms)
    {
        if !(e > 0.0 && e <= period_ms) {
            return Err(RuntimeError::Invalid(format!(
                "[source.live] exposure_ms (--exposure-ms): {e} ms is out of range (0 < exposure <= {period_ms:.3} \
                 ms, one frame period at {rate_from})"
            )));
        }
    }
    Ok(())
}

#[cfg(feature = "rerun")]
fn rerun_sink(p: &Path) -> Result<Box<dyn Sink>> {
    Ok(Box::new(crate::sinks::rerun_log::RerunSink::create(p)?))
}

#[cfg(not(feature = "rerun"))]
fn rerun_sink(p: &Path) -> Result<Box<dyn Sink>> {
    Err(RuntimeError::Invalid(format!(
        "--rerun (sinks.rerun) {}: this abvs was built without rerun logging; build it with \
         `cargo build --release -p abvs --features rerun` (abvs-runtime's cargo feature `rerun`)",
        p.display()
    )))
}

/// The configuration's output files, before any work (a soak must not lose its statistics at the end).
fn check_outputs(c: &RuntimeConfig) -> Result<()> {
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

#[cfg(test)]
mod overload_tests {
    use super::*;

    #[test]
    fn only_runs_that_dropped_frames_with_the_cores_busy_are_overloaded() {
        let cpu =
            |busy: f64| serde_json::json!({"cores_busy_without_idle_priority": busy, "cores": 2, "ms_per_frame": 78.0});
        let o = overload(&cpu(1.95), 12).expect("saturated and dropping");
        assert_eq!(o, Overload { dropped: 12, cores_busy: 1.95, cores: 2.0, ms_per_frame: 78.0 });
        // nothing dropped, or frames dropped with CPU to spare (a hiccup, not a shortage), or no CPU measured
        assert_eq!(overload(&cpu(1.95), 0), None);
        assert_eq!(overload(&cpu(1.2), 5), None);
        assert_eq!(overload(&serde_json::json!({}), 5), None);
        assert!(Overload::lighter("census-refine:hitnet-m4").contains("no `--model`"));
        // already the light network: only the resolution is left
        assert_eq!(Overload::lighter("census-refine:hitnet-s+sgbm"), "`--resolution 320x240`");
    }
}
