//! The steady-state allocation claim where `pipeline_alloc.rs` does not reach: with the real iceoryx2
//! publishing sink (depth and cloud to shared memory, with both engines), and under forced overload (a slow
//! sink, a paced source: queues full, the oldest frames dropped). Counted on every thread but the replay's
//! decode-ahead thread (see `pipeline_alloc.rs` for why that one is apart).
//!
//! What iceoryx2 0.10 itself allocates: one small block per loaned sample (`SampleMutUninit` keeps its shared
//! state in an `Arc`, freed at send; no public API avoids it), so publishing a frame (one depth map, one
//! cloud) allocates exactly two small blocks (three with the confidence); nothing of ours. Dropping frames
//! allocates nothing. The left-right check (the engine's second run on mirror buffers, the confidence
//! published) allocates nothing of its own either.
use std::alloc::{GlobalAlloc, Layout, System};
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use abvs_camera::StereoCalibration;
use abvs_disparity::factory as disparity;
use abvs_runtime::bridges::iceoryx::BridgeConfig;
use abvs_runtime::bridges::publish::PublishSink;
use abvs_runtime::pipeline::{run_replay, PipelineConfig};
use abvs_runtime::sources::replay::{on_decode_thread, ReplaySource};
use abvs_runtime::tasks::kinematics::{EyeFk, StereoKinematics};
use abvs_runtime_core::messages::Published;
use abvs_runtime_core::params::CheckConfig;
use abvs_runtime_core::session::Session;
use abvs_runtime_core::sink::Sink;

struct Counting;
/// Allocations of every thread but the replay's decoder, and the largest of them (bytes).
static ALLOCS: AtomicU64 = AtomicU64::new(0);
static LARGEST: AtomicU64 = AtomicU64::new(0);
/// Frames the probe saw with a confidence.
static WITH_CONFIDENCE: AtomicU64 = AtomicU64::new(0);

fn count(size: usize) {
    if !on_decode_thread() {
        ALLOCS.fetch_add(1, Ordering::Relaxed);
        LARGEST.fetch_max(size as u64, Ordering::Relaxed);
    }
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        count(l.size());
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        count(n);
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static A: Counting = Counting;

/// The counter is process-wide: the tests of this file run one at a time.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

/// Records the counter at every frame it sees (the vector is allocated up front) and resets the largest
/// allocation seen; sleeps `slow` per frame to force overload upstream.
struct Probe {
    marks: Arc<Mutex<Vec<(u64, u64)>>>,
    slow: Duration,
}

impl Sink for Probe {
    fn name(&self) -> &'static str {
        "probe"
    }
    fn consume(&mut self, p: &Published) -> abvs_runtime_core::error::Result<()> {
        if p.confidence.is_some() {
            WITH_CONFIDENCE.fetch_add(1, Ordering::Relaxed);
        }
        {
            let mut v = self.marks.lock().unwrap();
            if v.len() < v.capacity() {
                v.push((ALLOCS.load(Ordering::Relaxed), LARGEST.swap(0, Ordering::Relaxed)));
            }
        }
        if !self.slow.is_zero() {
            std::thread::sleep(self.slow);
        }
        Ok(())
    }
}

struct Run {
    /// Per frame after the first: allocations since the previous frame and the largest of them.
    per_frame: Vec<(u64, u64)>,
    published: u64,
    dropped: u64,
}

fn replay(engine: &str, publish: Option<&str>, cfg: PipelineConfig, slow: Duration) -> Run {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/session");
    let session = Session::open(&dir).unwrap();
    let stereo = StereoCalibration::read_yaml(session.path(&session.meta.stereo)).unwrap();
    let kin = StereoKinematics::new(
        EyeFk::load(&session.path(&session.meta.fk[0])).unwrap(),
        EyeFk::load(&session.path(&session.meta.fk[1])).unwrap(),
        stereo.rotation,
        stereo.translation_mm / 1000.0,
    );
    let model = dir.join("../../models/hitnet/hitnet-s");
    let eng = disparity::engine(engine, Some(&model), (cfg.out.width, cfg.out.height), 48.0, 2).unwrap();
    let marks = Arc::new(Mutex::new(Vec::with_capacity(1000)));
    let mut sinks: Vec<Box<dyn Sink>> = Vec::new();
    if let Some(prefix) = publish {
        let bc = BridgeConfig {
            prefix: prefix.into(),
            max_width: cfg.out.width,
            max_height: cfg.out.height,
            ..Default::default()
        };
        let sink = if cfg.check.confidence { PublishSink::with_confidence(bc) } else { PublishSink::new(bc) };
        sinks.push(Box::new(sink.unwrap()));
    }
    sinks.push(Box::new(Probe { marks: marks.clone(), slow }));
    let source = ReplaySource::open(session).unwrap();
    let stats = run_replay(source, kin, (stereo.left, stereo.right), eng, sinks, cfg).unwrap();
    let m = marks.lock().unwrap();
    Run {
        per_frame: m.windows(2).map(|w| (w[1].0 - w[0].0, w[1].1)).collect(),
        published: stats.frames_published,
        dropped: stats.frames_dropped,
    }
}

#[test]
fn publishing_to_iceoryx2_allocates_only_its_two_loans_per_frame_with_both_engines() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    for engine in ["sgbm", "onnx"] {
        let prefix = format!("abvs_alloc_test_{}_{engine}", std::process::id());
        let cfg = PipelineConfig { lossless: true, paced: false, frames: Some(150), ..Default::default() };
        let r = replay(engine, Some(&prefix), cfg, Duration::ZERO);
        assert_eq!(r.published, 150);
        // after a warm-up of 20 frames (lazy one-time initialisation in OpenCV / ONNX Runtime / iceoryx2)
        let steady = &r.per_frame[20..];
        let counts: Vec<u64> = steady.iter().map(|x| x.0).collect();
        let largest = steady.iter().map(|x| x.1).max().unwrap_or(0);
        eprintln!("{engine} + iceoryx2: allocations per frame {counts:?}, largest {largest} bytes");
        // Two per frame: the depth sample's and the cloud sample's loan (their frames' intervals may split
        // differently between probe marks, so judged in total and per frame at most 4), all small.
        let total: u64 = counts.iter().sum();
        assert_eq!(total, 2 * steady.len() as u64, "{engine}: {counts:?}");
        assert!(counts.iter().all(|&c| c <= 4), "{engine}: {counts:?}");
        assert!(largest <= 256, "{engine}: an allocation of {largest} bytes per frame");
    }
}

#[test]
fn the_left_right_check_and_publishing_its_confidence_allocate_only_the_three_loans_per_frame() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let prefix = format!("abvs_alloc_test_{}_confidence", std::process::id());
    let check = CheckConfig { confidence: true, invalidate: true, max_diff: 1.0 };
    let cfg = PipelineConfig { lossless: true, paced: false, frames: Some(120), check, ..Default::default() };
    WITH_CONFIDENCE.store(0, Ordering::Relaxed);
    let r = replay("sgbm", Some(&prefix), cfg, Duration::ZERO);
    assert_eq!(r.published, 120);
    assert_eq!(WITH_CONFIDENCE.load(Ordering::Relaxed), 120, "every frame carries its confidence");
    let steady = &r.per_frame[20..];
    let counts: Vec<u64> = steady.iter().map(|x| x.0).collect();
    let largest = steady.iter().map(|x| x.1).max().unwrap_or(0);
    eprintln!("sgbm + left-right check + iceoryx2: allocations per frame {counts:?}, largest {largest} bytes");
    // depth, confidence and cloud: one loan each
    let total: u64 = counts.iter().sum();
    assert_eq!(total, 3 * steady.len() as u64, "{counts:?}");
    assert!(counts.iter().all(|&c| c <= 6), "{counts:?}");
    assert!(largest <= 256, "an allocation of {largest} bytes per frame");
}

#[test]
fn dropping_the_oldest_frames_under_overload_allocates_nothing() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    // The fixture paced at its 25 fps, looped, into a sink that takes 80 ms a frame: the queues fill and
    // the oldest frames are dropped, every frame the sink sees being newer.
    let cfg = PipelineConfig { lossless: false, paced: true, frames: Some(150), ..Default::default() };
    let r = replay("sgbm", None, cfg, Duration::from_millis(80));
    eprintln!("overload: {} published, {} dropped; allocations per frame {:?}", r.published, r.dropped, r.per_frame);
    assert!(r.dropped >= 50, "overload not forced: {} dropped", r.dropped);
    let steady = &r.per_frame[10..];
    let total: u64 = steady.iter().map(|x| x.0).sum();
    assert_eq!(total, 0, "allocations while dropping: {:?}", r.per_frame);
}
