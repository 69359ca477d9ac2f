//! Faults the pipeline survives and counts: forced overload (a slow output sink, a slow disparity engine)
//! drops the oldest queued frames, counts them and keeps latency bounded by the queues; a source that stops
//! delivering (a frame file that never finishes reading) ends the run with the reason instead of hanging it.
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use abvs_camera::StereoCalibration;
use abvs_disparity::engine::DisparityEngine;
use abvs_disparity::factory as disparity;
use abvs_runtime::pipeline::{run_replay, PipelineConfig};
use abvs_runtime::sources::replay::ReplaySource;
use abvs_runtime::tasks::kinematics::{EyeFk, StereoKinematics};
use abvs_runtime_core::messages::Published;
use abvs_runtime_core::session::Session;
use abvs_runtime_core::sink::Sink;
use abvs_runtime_core::stats::RunStats;

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/session")
}

/// Replays `dir` through the pipeline with SGBM, an optional delay in the engine, and `sinks`.
fn replay(
    dir: &Path,
    cfg: PipelineConfig,
    engine_delay: Option<Duration>,
    sinks: Vec<Box<dyn Sink>>,
    stall: Duration,
) -> RunStats {
    let session = Session::open(dir).unwrap();
    let stereo = StereoCalibration::read_yaml(session.path(&session.meta.stereo)).unwrap();
    let kin = StereoKinematics::new(
        EyeFk::load(&session.path(&session.meta.fk[0])).unwrap(),
        EyeFk::load(&session.path(&session.meta.fk[1])).unwrap(),
        stereo.rotation,
        stereo.translation_mm / 1000.0,
    );
    let mut eng = disparity::engine("sgbm", None, (cfg.out.width, cfg.out.height), 48.0, 2).unwrap();
    if let Some(delay) = engine_delay {
        eng = Box::new(SlowEngine { inner: eng, delay });
    }
    let mut source = ReplaySource::open(session).unwrap();
    source.stall_timeout = stall;
    run_replay(source, kin, (stereo.left, stereo.right), eng, sinks, cfg).unwrap()
}

/// An output sink that takes `delay` per frame and records the seq of each frame it got.
struct SlowSink {
    delay: Option<Duration>,
    seqs: Arc<Mutex<Vec<u64>>>,
}

impl Sink for SlowSink {
    fn name(&self) -> &'static str {
        "slow"
    }
    fn consume(&mut self, out: &Published) -> abvs_runtime_core::error::Result<()> {
        if let Some(d) = self.delay {
            std::thread::sleep(d);
        }
        self.seqs.lock().unwrap().push(out.seq);
        Ok(())
    }
}

/// A disparity engine `delay` slower than the one it wraps.
struct SlowEngine {
    inner: Box<dyn DisparityEngine>,
    delay: Duration,
}

impl DisparityEngine for SlowEngine {
    fn name(&self) -> &str {
        "slow"
    }
    fn size(&self) -> (u32, u32) {
        self.inner.size()
    }
    fn max_disparity(&self) -> f64 {
        self.inner.max_disparity()
    }
    fn compute(&mut self, left: &[u8], right: &[u8], out: &mut [f32]) -> abvs_disparity::Result<()> {
        std::thread::sleep(self.delay);
        self.inner.compute(left, right, out)
    }
}

#[test]
fn forced_overload_drops_the_oldest_frames_counts_them_and_bounds_latency() {
    const FRAMES: u64 = 100;
    let slow = Duration::from_millis(100);
    for (what, sink_delay, engine_delay) in [("slow sink", Some(slow), None), ("slow engine", None, Some(slow))] {
        // frames at the session's 25 fps into a stage that manages 10 fps
        let cfg = PipelineConfig {
            frames: Some(FRAMES),
            paced: true,
            lossless: false,
            window: Duration::from_secs(1),
            ..Default::default()
        };
        let seqs = Arc::new(Mutex::new(Vec::new()));
        let sink = SlowSink { delay: sink_delay, seqs: seqs.clone() };
        let stats = replay(&fixture(), cfg, engine_delay, vec![Box::new(sink)], Duration::from_secs(5));
        let seqs = seqs.lock().unwrap().clone();
        let j = stats.json(1.0);
        eprintln!(
            "{what}: in {} published {} dropped {}, end to end p50 {} p99 {} max {} ms, windows {}",
            stats.frames_in,
            stats.frames_published,
            stats.frames_dropped,
            j["latency_ms"]["p50"],
            j["latency_ms"]["p99"],
            j["latency_ms"]["max"],
            j["windows"]
        );
        // every frame accounted for: published or dropped (counted), none failed
        assert_eq!(stats.frames_in, FRAMES, "{what}");
        assert_eq!(stats.frames_published + stats.frames_dropped, FRAMES, "{what}: {j}");
        assert!(stats.frames_failed.is_empty(), "{what}: {j}");
        // the stage's pace, not the source's: about 4 s x 10 fps published, the rest dropped
        assert!(stats.frames_dropped >= 30, "{what}: {j}");
        // dropped oldest first: what was published is in order and includes the newest frame (dropping the
        // newest, as a full pipeline used to, would lose the last frames)
        assert!(seqs.windows(2).all(|w| w[0] < w[1]), "{what}: {seqs:?}");
        assert_eq!(seqs.last(), Some(&(FRAMES - 1)), "{what}: {seqs:?}");
        // latency bounded by the queues (2 deep), whatever the machine: a frame waits for at most the one in
        // the slow stage and the one queued before it, then takes its own turn (3 x the slow stage), plus the
        // fast stages; a queue that grew would reach 4 s for the last frame (100 frames at 25 fps served at
        // 10 fps)
        let stage_p99 = |name: &str| j["stages"][name]["p99"].as_f64().unwrap();
        let slow_stage = if sink_delay.is_some() { "output" } else { "disparity" };
        let others: f64 = ["source", "rectify", "disparity", "output"]
            .iter()
            .filter(|s| **s != slow_stage)
            .map(|s| stage_p99(s))
            .sum();
        let bound = 3.0 * stage_p99(slow_stage) + others + 50.0;
        let p99 = j["latency_ms"]["p99"].as_f64().unwrap();
        eprintln!("{what}: end-to-end p99 {p99} ms, bound {bound:.1} ms");
        assert!(p99 <= bound, "{what}: end-to-end p99 {p99} ms over the bound {bound:.1} ms");
        assert!(bound < 2000.0, "{what}: stages far slower than expected: {j}");
    }
}

#[test]
fn a_source_that_stops_delivering_ends_the_run_with_the_reason() {
    let d = tempfile::tempdir().unwrap();
    let s = d.path().join("s");
    assert!(Command::new("cp").arg("-r").arg(fixture()).arg(&s).status().unwrap().success());
    // frame 10's left file becomes a FIFO nobody writes: opening it blocks, like a read from a hung mount
    let fifo = s.join("frames/left_000010.png");
    std::fs::remove_file(&fifo).unwrap();
    assert!(Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    let seqs = Arc::new(Mutex::new(Vec::new()));
    let sink = SlowSink { delay: None, seqs: seqs.clone() };
    let cfg = PipelineConfig { frames: Some(50), paced: false, lossless: true, ..Default::default() };
    // the run on its own thread, so a hang fails the test instead of stalling it
    let (tx, rx) = std::sync::mpsc::channel();
    let dir = s.clone();
    std::thread::spawn(move || {
        let stats = replay(&dir, cfg, None, vec![Box::new(sink)], Duration::from_secs(1));
        let _ = tx.send(stats);
    });
    let stats = rx.recv_timeout(Duration::from_secs(60)).expect("the run ended (no hang)");
    let j = stats.json(1.0);
    eprintln!("stalled source: {}", serde_json::to_string(&j).unwrap());
    // the ten frames before the stall are through, the reason is in the statistics
    assert_eq!((stats.frames_in, stats.frames_published, stats.frames_dropped), (10, 10, 0), "{j}");
    assert_eq!(*seqs.lock().unwrap(), (0..10).collect::<Vec<u64>>());
    let why = j["source_ended"].as_str().expect("source_ended");
    assert!(why.contains("stalled") && why.contains("left_000010.png"), "{why}");
    assert!(stats.frames_failed.is_empty(), "{j}");
    // release the decoder still blocked in open()
    drop(std::fs::OpenOptions::new().write(true).open(&fifo).unwrap());
}
