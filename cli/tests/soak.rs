//! Soak: `abvs run --loop --seconds N` replays the fixture session in a loop at its frame rate through the
//! whole runtime (default engine, ground-truth scoring, the self-check, iceoryx2 publishing) and reports per
//! statistics window the latency p50/p99, the counts and the resident memory. The claim: after the first
//! part, resident memory does not grow (under 2 MB after the first two windows in CI's 30 s; over 10 minutes
//! or more, the run's steady slope under 0.1 MB/min), and every window keeps publishing with bounded latency.
//!
//! CI runs 30 s at 320x240 in 2.5 s windows: the first two hold the start-up, so memory a run takes on in
//! its first seconds after that (the truth lane's pool, made as its worker fell behind: issue 42, 16 MB/min
//! here before the fix) reads as growth. `ABVS_SOAK_SECONDS=1800` runs the 30-minute soak of
//! runtime/BENCHMARKS.md (which used the release build directly: see there).
use std::process::Command;

use serde_json::Value;

#[test]
fn a_looped_replay_keeps_resident_memory_flat_and_latency_bounded() {
    let secs: f64 =
        std::env::var("ABVS_SOAK_SECONDS").map(|s| s.parse().expect("ABVS_SOAK_SECONDS: seconds")).unwrap_or(30.0);
    // 12 windows: the first two are the first part (models loaded, buffers first touched, allocator arenas
    // filled), the other ten are judged
    let window = secs / 12.0;
    let dir = tempfile::tempdir().unwrap();
    let stats = dir.path().join("stats.json");
    let out = Command::new(env!("CARGO_BIN_EXE_abvs"))
        .args([
            "run",
            "--resolution",
            "320x240",
            "--quiet",
            // what a soak must hold with: depth scored against the truth, the self-check on
            "--truth-stride",
            "8",
            "--self-check",
            "--loop",
            "--seconds",
            &secs.to_string(),
            "--stats-window",
            &window.to_string(),
        ])
        .args(["--service-prefix", &format!("abvs-soak-{}", std::process::id())])
        .arg("--stats-json")
        .arg(&stats)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
    let windows = v["windows"].as_array().unwrap();
    let f = |w: &Value, k: &str| w[k].as_f64().unwrap_or(f64::NAN);
    for w in windows {
        eprintln!(
            "t {:6.1} s  in {:4}  published {:4}  dropped {:3}  p50 {:7.2} ms  p99 {:7.2} ms  rss {:7.1} MB",
            f(w, "t_s"),
            w["frames_in"],
            w["frames_published"],
            w["frames_dropped"],
            f(w, "p50_ms"),
            f(w, "p99_ms"),
            f(w, "rss_mb")
        );
    }
    eprintln!("rss: {}", v["rss"]);
    // the run: as long as asked, every frame accounted for
    let elapsed = v["elapsed_s"].as_f64().unwrap();
    assert!(elapsed >= secs && elapsed < secs + 5.0, "ran {elapsed} s for --seconds {secs}");
    assert_eq!(v["frames_failed"], serde_json::json!({}), "{v}");
    let n = |k: &str| v[k].as_u64().unwrap();
    assert_eq!(n("frames_in"), n("frames_published") + n("frames_dropped"), "{v}");
    assert!(n("frames_in") as f64 >= 0.95 * 25.0 * secs, "the paced source kept 25 fps: {v}");

    // the judged windows: complete ones (the last, cut-short window holds the frames in flight at the end)
    // after the first part
    let judged: Vec<&Value> = windows
        .iter()
        .enumerate()
        .filter(|(i, w)| {
            let start = if *i == 0 { 0.0 } else { f(&windows[i - 1], "t_s") };
            f(w, "t_s") > 2.0 * window + 1e-3 && f(w, "t_s") - start >= 0.9 * window
        })
        .map(|(_, w)| w)
        .collect();
    assert!(judged.len() >= 9, "{} windows judged of {}", judged.len(), windows.len());
    for w in &judged {
        // each window kept publishing (under load, here a debug build beside other builds, drops are fine:
        // counted, oldest first) with latency bounded by the queues: 2.5 s leaves room for a machine ten
        // times slower than the fixture needs, where a queue that grew would reach tens of seconds
        assert!(w["frames_published"].as_u64().unwrap() > 0, "{w}");
        assert!(f(w, "p99_ms") < 2500.0, "{w}");
    }
    let rss: Vec<(f64, f64)> = judged.iter().map(|w| (f(w, "t_s") / 60.0, f(w, "rss_mb"))).collect();
    let (lo, hi) = rss.iter().fold((f64::INFINITY, 0f64), |(lo, hi), p| (lo.min(p.1), hi.max(p.1)));
    assert!(lo > 10.0, "resident memory read: {rss:?}");
    assert!((hi - lo) / lo <= 0.05, "resident memory not flat within 5 %: {lo:.1} .. {hi:.1} MB: {rss:?}");
    // no growth: the run's own least-squares slope over its windows after the first (`rss`), under 0.1 MB/min
    // (a day's soak: 144 MB at most). Scoring depth against the truth and the self-check keep nothing per
    // frame: their pools, histograms and rings are resident from the start (issue 42: the truth lane's pool,
    // made as its worker fell behind and grown as larger clouds came, read 6.5 MB/min).
    let slope = v["rss"]["steady_slope_mb_per_min"].as_f64().unwrap_or(f64::NAN);
    eprintln!("resident memory over the judged windows: {lo:.3} .. {hi:.3} MB, steady slope {slope:.4} MB/min");
    // In 30 s a one-time step still reads as a slope: the release build at 320x240 takes on 0.63 MB once,
    // 7.5-10 s into the run, flat after (the default engine's, census-refine / ONNX Runtime: not with
    // --engine sgbm), 1.3 MB/min over 30 s. So the CI run bounds what the windows after the first part (two
    // windows) take on (before the fix: 3.4 and 12.7 MB from the first window in two debug runs; after:
    // 0.66 MB), and a run of 10 minutes or more (ABVS_SOAK_SECONDS) the slope itself. The first part, not the
    // first window: on a fresh machine (2026-11-28) the debug build still took on 1.37 MB of start-up in the
    // second window (2.19 MB from the first, 0.82 MB over the judged windows).
    let first = windows[1]["rss_mb"].as_f64().unwrap();
    let grown = windows.iter().skip(1).map(|w| f(w, "rss_mb")).fold(f64::NEG_INFINITY, f64::max) - first;
    assert!(grown < 2.0, "resident memory grew {grown:.2} MB after the first part: {}", v["rss"]);
    if secs >= 600.0 {
        assert!(slope < 0.1, "resident memory grows {slope:.3} MB/min: {}", v["rss"]);
    }
}

/// A looped run without --seconds runs until stopped: SIGTERM (or Ctrl-C) ends it cleanly, with its
/// statistics written as at the end of a replay (a soak stopped by hand still reports).
#[test]
fn a_looped_run_stopped_by_a_signal_still_reports() {
    let dir = tempfile::tempdir().unwrap();
    let stats = dir.path().join("stats.json");
    let child = Command::new(env!("CARGO_BIN_EXE_abvs"))
        .args([
            "run",
            "--resolution",
            "320x240",
            "--quiet",
            "--engine",
            "sgbm",
            "--truth-stride",
            "0",
            "--loop",
            "--stats-window",
            "1",
        ])
        .args(["--service-prefix", &format!("abvs-soak-stop-{}", std::process::id())])
        .arg("--stats-json")
        .arg(&stats)
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_secs(4));
    assert!(Command::new("kill").args(["-TERM", &child.id().to_string()]).status().unwrap().success());
    let t0 = std::time::Instant::now();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "{:?}: {}", out.status, String::from_utf8_lossy(&out.stderr));
    assert!(t0.elapsed() < std::time::Duration::from_secs(5), "stopping took {:?}", t0.elapsed());
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
    let n = |k: &str| v[k].as_u64().unwrap();
    eprintln!("stopped after {} s: in {} published {}", v["elapsed_s"], n("frames_in"), n("frames_published"));
    assert!(n("frames_in") >= 25, "{v}");
    assert_eq!(n("frames_in"), n("frames_published") + n("frames_dropped"), "{v}");
    assert!(!v["windows"].as_array().unwrap().is_empty(), "{v}");
}
