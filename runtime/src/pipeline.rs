//! The runtime's standard stage graph, and the entry points that run it.
//!
//! ```text
//! source ──q──> rectify lane ──q──> disparity lane ──q──> output lane ──> sinks and bridges
//!               align, kinematics,   disparity (+ its     depth
//!               rectify              left-right check)
//! ```
//! [`STANDARD_GRAPH`] says which stage runs on which lane; [`graph`] builds it for a source, the calibration
//! and an engine, and [`crate::runner`] runs it (queues, pooled buffers, drop-oldest, statistics). A
//! deployment adds sinks or side stages to the [`Graph`] without touching either.
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

use abvs_camera::Camera;

use crate::gaze::stage::GazeStage;
use crate::runner::{Graph, Lane, Progress, RunConfig};
use crate::sources::replay::ReplaySource;
use crate::tasks::align::AlignStage;
use crate::tasks::depth::{DepthConfig, DepthStage};
use crate::tasks::disparity::DisparityStage;
use crate::tasks::fovea::FoveaStage;
use crate::tasks::kinematics::{KinematicsStage, StereoKinematics};
use crate::tasks::rectify::RectifyStage;
use abvs_disparity::engine::DisparityEngine;
use abvs_runtime_core::error::Result;
use abvs_runtime_core::messages::RectifiedCamera;
use abvs_runtime_core::params::CheckConfig;
use abvs_runtime_core::params::FoveaConfig;
use abvs_runtime_core::params::MotionConfig;
use abvs_runtime_core::sink::Sink;
use abvs_runtime_core::source::PairSource;
use abvs_runtime_core::stage::Stage;
use abvs_runtime_core::stats::RunStats;

/// The lanes of the standard graph (one thread each; the last runs the sinks). Alignment, kinematics and
/// rectification share a lane: each is well under a millisecond, and a queue between them would add a
/// hand-off per frame for no parallelism worth having.
pub const STANDARD_GRAPH: &str = "rectify = align, kinematics, rectify; disparity = disparity; output = depth";

/// The standard graph with the gaze stage after kinematics ([`crate::gaze`]): the runtime's graph.
pub const GAZE_GRAPH: &str = "rectify = align, kinematics, gaze, rectify; disparity = disparity; output = depth";

/// The latency histograms of the standard graph: the source, then its lanes.
pub const STAGES: [&str; 4] = ["source", "rectify", "disparity", "output"];

/// What the standard graph runs with: the rectified output, the stages' settings and how frames move.
#[derive(Debug, Clone)]
pub struct PipelineConfig {
    /// The rectified output camera (resolution, focal length) every stage after rectification works at.
    pub out: RectifiedCamera,
    /// Node spacing of the rectification map grid (px).
    pub grid_step: u32,
    /// Depth and cloud from disparity.
    pub depth: DepthConfig,
    /// Rolling-shutter correction, the motion gate, an encoder time offset override.
    pub motion: MotionConfig,
    /// The disparity's left-right check: confidence per frame, inconsistent pixels invalidated (default:
    /// neither, the check does not run).
    pub check: CheckConfig,
    /// The validity mask's threshold on the engine's own confidence (census-refine): depth NaN below it; 0
    /// keeps every pixel (default here: 0; the deployment's default is
    /// `abvs_runtime_core::params::DEFAULT_MIN_CONFIDENCE`).
    pub min_confidence: f32,
    /// Capacity of each inter-stage queue.
    pub queue: usize,
    /// Block instead of dropping: every frame is processed (offline, reproducible).
    pub lossless: bool,
    /// Release replayed frames at their recorded times (as a live camera would).
    pub paced: bool,
    /// Number of frames (looping the session); `None` plays it once.
    pub frames: Option<u64>,
    /// Stop taking frames from the source this long after the start (the frames in flight finish).
    pub duration: Option<Duration>,
    /// Length of a statistics window: latency percentiles, counts and resident memory per window
    /// ([`RunStats::windows`]).
    pub window: Duration,
    /// Stop taking frames once this is set (Ctrl-C, SIGTERM): the frames in flight finish and the run
    /// returns its statistics as at the end of a replay.
    pub stop: Option<Arc<AtomicBool>>,
    /// Counters for another thread to read while the run goes ([`Progress`]).
    pub progress: Option<Arc<Progress>>,
    /// The fovea ([`crate::tasks::fovea`]), on a lane of its own between disparity and output; `None` runs
    /// the graph without it (the main outputs are the same either way).
    pub fovea: Option<FoveaConfig>,
}

impl Default for PipelineConfig {
    fn default() -> Self {
        PipelineConfig {
            out: RectifiedCamera::with_hfov(320, 240, 100.0),
            grid_step: 8,
            depth: DepthConfig::default(),
            motion: MotionConfig::default(),
            check: CheckConfig::default(),
            min_confidence: 0.0,
            queue: 2,
            lossless: false,
            paced: true,
            frames: None,
            duration: None,
            window: Duration::from_secs(60),
            stop: None,
            progress: None,
            fovea: None,
        }
    }
}

impl PipelineConfig {
    /// The runner's part of the configuration.
    pub fn run_config(&self) -> RunConfig {
        RunConfig {
            queue: self.queue,
            lossless: self.lossless,
            paced: self.paced,
            frames: self.frames,
            duration: self.duration,
            window: self.window,
            stop: self.stop.clone(),
            progress: self.progress.clone(),
        }
    }
}

/// The standard graph ([`STANDARD_GRAPH`]) for a source, both eyes' kinematics and lenses, and an engine.
pub fn graph<S: PairSource>(
    source: S,
    kin: StereoKinematics,
    cams: (Camera, Camera),
    engine: Box<dyn DisparityEngine>,
    sinks: Vec<Box<dyn Sink>>,
    cfg: &PipelineConfig,
) -> Result<Graph<S>> {
    graph_with_gaze(source, kin, cams, engine, sinks, cfg, None)
}

/// [`graph`], with the gaze stage after kinematics when given one ([`GAZE_GRAPH`]).
pub fn graph_with_gaze<S: PairSource>(
    source: S,
    kin: StereoKinematics,
    cams: (Camera, Camera),
    engine: Box<dyn DisparityEngine>,
    sinks: Vec<Box<dyn Sink>>,
    cfg: &PipelineConfig,
    gaze: Option<GazeStage>,
) -> Result<Graph<S>> {
    let fovea = cfg.fovea.map(|f| FoveaStage::new(f, cams, kin.home_left_to_right, cfg.grid_step, cfg.depth));
    let kinematics = KinematicsStage::new(kin).with_motion(cfg.motion);
    let mut stages: Vec<Box<dyn Stage>> =
        vec![Box::new(AlignStage::new(kinematics.encoder_latency_s()).with_motion(cfg.motion)), Box::new(kinematics)];
    let description = match gaze {
        Some(g) => {
            stages.push(Box::new(g));
            GAZE_GRAPH
        }
        None => STANDARD_GRAPH,
    };
    stages.push(Box::new(RectifyStage::new(cams, cfg.grid_step)));
    let dense = sinks.iter().any(|s| s.wants_dense_disparity());
    let disparity = DisparityStage::with_check(engine, cfg.check)?.with_min_confidence(cfg.min_confidence)?;
    stages.push(Box::new(disparity.with_dense_kept(dense)));
    stages.push(Box::new(DepthStage::new(cfg.depth)));
    let mut g = Graph::from_description(source, cfg.out, description, stages, sinks)?;
    if let Some(f) = fovea {
        // a lane of its own before the output: it reads the main map's disparity and overlaps the next frame's
        let at = g.lanes.len() - 1;
        g.lanes.insert(at, Lane { name: FOVEA_LANE, stages: vec![Box::new(f)] });
    }
    Ok(g)
}

/// The fovea's lane (and its latency histogram and CPU in the statistics).
pub const FOVEA_LANE: &str = "fovea";

/// Runs a replay through the whole pipeline and returns its statistics.
pub fn run_replay(
    source: ReplaySource,
    kin: StereoKinematics,
    cams: (Camera, Camera),
    engine: Box<dyn DisparityEngine>,
    sinks: Vec<Box<dyn Sink>>,
    cfg: PipelineConfig,
) -> Result<RunStats> {
    // (unusable frame files are reported on stderr as the replay reaches them)
    run(source, kin, cams, engine, sinks, cfg)
}

/// Runs any pair source through the standard graph and returns its statistics.
pub fn run<S: PairSource>(
    source: S,
    kin: StereoKinematics,
    cams: (Camera, Camera),
    engine: Box<dyn DisparityEngine>,
    sinks: Vec<Box<dyn Sink>>,
    cfg: PipelineConfig,
) -> Result<RunStats> {
    crate::runner::run(graph(source, kin, cams, engine, sinks, &cfg)?, &cfg.run_config())
}

/// [`run`] with the gaze stage ([`GAZE_GRAPH`]).
pub fn run_with_gaze<S: PairSource>(
    source: S,
    kin: StereoKinematics,
    cams: (Camera, Camera),
    engine: Box<dyn DisparityEngine>,
    sinks: Vec<Box<dyn Sink>>,
    cfg: PipelineConfig,
    gaze: Option<GazeStage>,
) -> Result<RunStats> {
    crate::runner::run(graph_with_gaze(source, kin, cams, engine, sinks, &cfg, gaze)?, &cfg.run_config())
}
