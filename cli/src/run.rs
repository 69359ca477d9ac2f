//! `abvs run`: the runtime's main job. Replays a recorded session (by default the embedded fixture) through
//! the whole pipeline: time alignment, per-eye FK, moving extrinsic, rectification, disparity, depth and
//! cloud, publishing; prints the latency table and optionally writes the statistics as JSON.
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use abvs_camera::StereoCalibration;
use abvs_runtime::pipeline::{run_replay, PipelineConfig, Sink};
use abvs_runtime::session::Session;
use abvs_runtime::sinks::truth::TruthSink;
use abvs_runtime::sources::replay::ReplaySource;
use abvs_runtime::tasks::disparity;
use abvs_runtime::tasks::kinematics::{EyeFk, StereoKinematics};
use abvs_runtime::tasks::rectify::RectifiedCamera;
use anyhow::{bail, Context};
use clap::Args;

#[derive(Args)]
pub struct RunArgs {
    /// Session directory to replay (default: the embedded fixture, fixtures/session).
    #[arg(long)]
    pub session: Option<PathBuf>,
    /// Number of frames (the session loops when shorter, timestamps kept increasing); default one pass.
    #[arg(long)]
    pub frames: Option<u64>,
    /// Write the statistics as JSON.
    #[arg(long)]
    pub stats_json: Option<PathBuf>,
    /// Disparity engine: onnx (the shipped network) or sgbm (OpenCV).
    #[arg(long, default_value = "onnx")]
    pub engine: String,
    /// Disparity model directory or .onnx (default: models/hitnet/hitnet-s at 320x240, hitnet-m at 640x480).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Network resolution "WxH" (320x240 or 640x480 for the shipped models).
    #[arg(long, default_value = "320x240")]
    pub resolution: String,
    /// Horizontal field of view of the rectified images (deg).
    #[arg(long, default_value_t = 100.0)]
    pub rect_hfov: f64,
    /// FK used for the eyes: the session's calibrated models, the ideal mechanism (nominal), or the true units
    /// of a synthetic session (truth: the floor set by stereo matching alone).
    #[arg(long, default_value = "calibrated")]
    pub fk: String,
    /// Process every frame (queues block instead of dropping the oldest) and replay as fast as possible.
    #[arg(long)]
    pub lossless: bool,
    /// Do not pace the replay at the recorded frame rate.
    #[arg(long)]
    pub no_pace: bool,
    /// Threads of the ONNX engine.
    #[arg(long, default_value_t = 2)]
    pub threads: usize,
    /// Score depth against the session's ground truth every N-th point (synthetic sessions; 0: off).
    #[arg(long, default_value_t = 8)]
    pub truth_stride: usize,
    /// Write each frame's rectified pair and depth as PNG into this directory (slow; for looking).
    #[arg(long)]
    pub dump: Option<PathBuf>,
    /// Log rectified images, depth, the cloud and both moving camera frustums to this rerun file (.rrd;
    /// needs the cargo feature `rerun`).
    #[arg(long)]
    pub rerun: Option<PathBuf>,
    /// Do not publish over iceoryx2.
    #[arg(long)]
    pub no_publish: bool,
    /// iceoryx2 service name prefix (services {prefix}/depth, {prefix}/cloud).
    #[arg(long, default_value = "abvs")]
    pub service_prefix: String,
    /// Do not print the latency table.
    #[arg(long)]
    pub quiet: bool,
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

pub fn run(a: RunArgs) -> anyhow::Result<ExitCode> {
    let dir = a.session.clone().unwrap_or_else(|| shipped("fixtures/session"));
    let session = Session::open(&dir).with_context(|| format!("opening session {}", dir.display()))?;
    let (w, h) = parse_resolution(&a.resolution)?;
    let stereo_path = session.path(&session.meta.stereo);
    let stereo = StereoCalibration::read_yaml(&stereo_path)?;
    let (left, right) = match a.fk.as_str() {
        "calibrated" => {
            (EyeFk::load(&session.path(&session.meta.fk[0]))?, EyeFk::load(&session.path(&session.meta.fk[1]))?)
        }
        "nominal" => (EyeFk::nominal(), EyeFk::nominal()),
        "truth" => {
            let t = session.meta.truth.as_ref().context("--fk truth needs a synthetic session (with truth/)")?;
            (EyeFk::load(&session.path(&t.units[0]))?, EyeFk::load(&session.path(&t.units[1]))?)
        }
        other => bail!("--fk `{other}`: expected calibrated or nominal"),
    };
    let mut kin = StereoKinematics::new(left, right, stereo.rotation, stereo.translation_mm / 1000.0);
    kin.gravity = session.meta.gravity;
    let out = RectifiedCamera::with_hfov(w, h, a.rect_hfov);
    // disparity range for the eyes' working range at this resolution: f B / z_min
    let max_disp = out.f * stereo.baseline_mm() / 1000.0 / 0.2;
    let model = match (&a.model, a.engine.as_str()) {
        (Some(m), _) => Some(m.clone()),
        (None, "onnx") => {
            let variant = if w >= 640 { "hitnet-m" } else { "hitnet-s" };
            Some(shipped(&format!("models/hitnet/{variant}")))
        }
        _ => None,
    };
    let engine = disparity::engine(&a.engine, model.as_deref(), (w, h), max_disp, a.threads)?;
    let mut sinks: Vec<Box<dyn Sink>> = Vec::new();
    if a.truth_stride > 0 {
        if let Some(t) = TruthSink::for_session(&session, a.truth_stride)? {
            sinks.push(Box::new(t));
        }
    }
    if !a.no_publish {
        let cfg =
            abvs_runtime::bridges::iceoryx::BridgeConfig::for_resolution(w, h).with_prefix(a.service_prefix.clone());
        sinks.push(Box::new(abvs_runtime::bridges::publish::PublishSink::new(cfg)?));
    }
    if let Some(p) = &a.rerun {
        sinks.push(rerun_sink(p)?);
    }
    if let Some(d) = &a.dump {
        sinks.push(Box::new(abvs_runtime::sinks::dump::DumpSink { dir: d.clone(), every: 1 }));
    }
    let description = session.meta.description.clone();
    let source = ReplaySource::open(session)?;
    let cfg = PipelineConfig {
        out,
        lossless: a.lossless,
        paced: !(a.no_pace || a.lossless),
        frames: a.frames,
        ..Default::default()
    };
    let engine_name = engine.name().to_string();
    let mut stats = run_replay(source, kin, (stereo.left, stereo.right), engine, sinks, cfg)?;
    stats.extra.insert("session".into(), serde_json::json!(dir.display().to_string()));
    stats.extra.insert("engine".into(), serde_json::json!(engine_name));
    stats.extra.insert("fk".into(), serde_json::json!(a.fk));
    stats.extra.insert("resolution".into(), serde_json::json!([w, h]));
    let elapsed = stats.extra.get("elapsed_s").and_then(|v| v.as_f64()).unwrap_or(0.0);
    if !a.quiet {
        println!("session {} ({description})", dir.display());
        println!("engine {engine_name} at {w}x{h}, fk {}", a.fk);
        print!("{}", stats.table(elapsed));
    }
    if let Some(p) = &a.stats_json {
        std::fs::write(p, serde_json::to_string_pretty(&stats.json(elapsed))? + "\n")
            .with_context(|| format!("writing {}", p.display()))?;
    }
    Ok(ExitCode::SUCCESS)
}
