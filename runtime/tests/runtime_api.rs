//! The embedding API on the real fixture: a handle stops a run without end, the configuration's outputs are
//! written by the library, and bad input is refused by `Runtime::from_config` before any frame, naming what
//! is wrong.
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use abvs_runtime::shipped::shipped;
use abvs_runtime::Runtime;
use abvs_runtime_core::config::{EngineKind, RuntimeConfig, SourceKind};
use abvs_runtime_core::error::RuntimeError;

/// The fixture at 320x240 with SGBM (the cheapest engine), publishing nothing.
fn small() -> RuntimeConfig {
    let mut c = RuntimeConfig::for_session(shipped("fixtures/session"));
    c.disparity.width = 320;
    c.disparity.height = 240;
    c.disparity.engine = EngineKind::Sgbm;
    c.bridges.iceoryx.enabled = false;
    c
}

fn refusal(c: &RuntimeConfig) -> String {
    match Runtime::from_config(c) {
        Ok(_) => panic!("accepted: {c:?}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn a_handle_stops_a_run_without_end_and_its_counts_follow_it() {
    let mut c = small();
    // paced at the recorded 25 fps, looping: it would not end alone for a minute (a stop not heard fails the
    // test below instead of hanging it)
    c.source.looping = true;
    c.source.seconds = Some(60.0);
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("stats.json");
    c.sinks.stats_json = Some(json.clone());
    let handle = Runtime::from_config(&c).unwrap().spawn().unwrap();
    let t0 = Instant::now();
    while handle.stats().frames_published < 5 {
        assert!(!handle.is_finished(), "the run ended alone");
        assert!(t0.elapsed() < Duration::from_secs(60), "5 frames not published in 60 s: {:?}", handle.stats());
        std::thread::sleep(Duration::from_millis(20));
    }
    handle.stop();
    let (seen, stopped) = (handle.stats(), Instant::now());
    let report = handle.join().unwrap();
    assert!(stopped.elapsed() < Duration::from_secs(10), "the stop took {:?}", stopped.elapsed());
    let s = &report.stats;
    // it stopped: the frames in flight finished, no more were taken
    assert!(s.frames_published >= seen.frames_published && s.frames_in <= seen.frames_in + 1, "{seen:?}");
    assert!(s.frames_in < 50 * 4, "{} frames: the stop was not heard", s.frames_in);
    assert_eq!(s.frames_in, s.frames_published + s.frames_dropped + s.frames_failed.values().sum::<u64>());
    assert_eq!(report.engine, "sgbm");
    // the library wrote the configuration's statistics file, with what it adds to the run's statistics
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["frames_published"], s.frames_published);
    assert_eq!(v["engine"], "sgbm");
    assert_eq!(v["resolution"], serde_json::json!([320, 240]));
}

#[test]
fn run_until_a_flag_set_before_the_start_takes_no_frame() {
    let stop = Arc::new(AtomicBool::new(true));
    let report = Runtime::from_config(&small()).unwrap().run_until(stop.clone()).unwrap();
    assert!(stop.load(Ordering::Relaxed));
    assert_eq!((report.stats.frames_in, report.stats.frames_published), (0, 0));
}

#[test]
fn bad_configurations_are_refused_before_any_frame_naming_what_is_wrong() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = small();
    c.source.session = Some(dir.path().join("no-session"));
    let e = refusal(&c);
    assert!(e.contains("no-session") && e.contains("session.toml"), "{e}");

    let mut c = small();
    c.sinks.stats_json = Some(dir.path().join("missing/stats.json"));
    let e = refusal(&c);
    assert!(e.starts_with("sinks.stats_json ") && e.contains("does not exist"), "{e}");

    let mut c = small();
    c.disparity.min_depth_m = 0.0;
    let e = refusal(&c);
    assert!(e.contains("configuration: disparity.min_depth_m"), "{e}");

    let mut c = small();
    c.disparity.engine = EngineKind::Onnx;
    c.disparity.model = Some(dir.path().join("no-model.onnx"));
    let e = refusal(&c);
    assert!(e.contains("no-model.onnx"), "{e}");

    // live: the calibration is loaded before any device, then the encoder port is the first device opened
    let mut c = small();
    c.source.kind = SourceKind::Live;
    c.calibration.dir = Some(dir.path().join("no-calib"));
    let e = refusal(&c);
    assert!(e.contains("no-calib"), "{e}");
    c.calibration.dir = Some(shipped("fixtures/session/calib"));
    c.source.live.encoders = dir.path().join("no-tty").display().to_string();
    let e = refusal(&c);
    assert!(e.contains("encoder port") && e.contains("no-tty"), "{e}");
    assert!(matches!(Runtime::from_config(&c), Err(RuntimeError::Device(_))));
}
