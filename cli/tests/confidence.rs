//! The confidence of `abvs run --confidence` end to end: a real run on the fixture (real ONNX Runtime, the
//! shipped network) publishes `{prefix}/confidence` next to `{prefix}/depth` over real iceoryx2; subscribers
//! in this process (and a real `abvs echo confidence`) receive both, matched by `seq`. The confidence must
//! rank the depth: against the fixture's ground truth (the truth sink's `depth_error_by_confidence`), the
//! points of confidence > 0.8 are more accurate than the others.
use std::collections::HashMap;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use abvs_runtime::bridges::iceoryx::{BridgeConfig, FrameHeader, Subscriber};
use serde_json::Value;

type Frames = HashMap<u64, (FrameHeader, Vec<f32>)>;

/// Receives one `[f32]` topic until `stop`, keeping every sample by seq.
fn collect(mut sub: Subscriber<f32>, stop: Arc<AtomicBool>) -> JoinHandle<Frames> {
    std::thread::spawn(move || {
        let mut out = Frames::new();
        loop {
            match sub.wait(Duration::from_millis(200)).unwrap() {
                Some(r) => {
                    out.insert(r.header().seq, (*r.header(), r.data().to_vec()));
                }
                None if stop.load(Ordering::Relaxed) => return out,
                None => {}
            }
        }
    })
}

struct Received {
    depth: Frames,
    confidence: Frames,
    stats: Value,
}

/// `abvs run --lossless --quiet` on the fixture with `extra`, received over iceoryx2 under a fresh prefix;
/// with `echo`, a real `abvs echo confidence --count 5 --json` runs alongside and its JSON is returned too.
fn run(name: &str, extra: &[&str], echo: bool) -> (Received, Option<Value>) {
    let prefix = format!("abvs-conf-{}-{name}", std::process::id());
    let cfg = BridgeConfig::for_resolution(320, 240).with_prefix(prefix.clone());
    let echo = echo.then(|| {
        Command::new(env!("CARGO_BIN_EXE_abvs"))
            .args(["echo", "confidence", "--count", "5", "--json", "--timeout-s", "60", "--prefix", &prefix])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    });
    let stop = Arc::new(AtomicBool::new(false));
    let depth = collect(Subscriber::<f32>::new(&cfg).unwrap(), stop.clone());
    let confidence = collect(Subscriber::<f32>::confidence(&cfg).unwrap(), stop.clone());
    if echo.is_some() {
        // the echo process's subscriber exists before the first frame (the run loads its network first, too)
        std::thread::sleep(Duration::from_millis(1000));
    }
    let d = tempfile::tempdir().unwrap();
    let stats = d.path().join("stats.json");
    let o = Command::new(env!("CARGO_BIN_EXE_abvs"))
        .args([
            "run",
            "--resolution",
            "320x240",
            "--lossless",
            "--quiet",
            "--service-prefix",
            &prefix,
            "--stats-json",
            stats.to_str().unwrap(),
            // the left-right check alone: no validity mask before it (census-refine's own confidence)
            "--min-confidence",
            "0",
        ])
        .args(extra)
        .output()
        .unwrap();
    assert!(o.status.success(), "abvs run: {}", String::from_utf8_lossy(&o.stderr));
    std::thread::sleep(Duration::from_millis(300));
    stop.store(true, Ordering::Relaxed);
    let (depth, confidence) = (depth.join().unwrap(), confidence.join().unwrap());
    let echo = echo.map(|c| {
        let out = c.wait_with_output().unwrap();
        assert!(out.status.success(), "abvs echo confidence: {}", String::from_utf8_lossy(&out.stderr));
        serde_json::from_str(String::from_utf8_lossy(&out.stdout).lines().last().unwrap()).unwrap()
    });
    let stats = serde_json::from_str(&std::fs::read_to_string(stats).unwrap()).unwrap();
    (Received { depth, confidence, stats }, echo)
}

/// The frames received on both topics, by seq; checks they describe the same frame.
fn matched(r: &Received) -> Vec<(&FrameHeader, &[f32], &[f32])> {
    let mut seqs: Vec<u64> = r.confidence.keys().copied().filter(|s| r.depth.contains_key(s)).collect();
    seqs.sort();
    // lossless: the runtime publishes all 50 frames; a subscriber may miss some (safe overflow) but not most
    assert!(
        seqs.len() >= 25,
        "{} frames on both topics ({} depth, {} confidence)",
        seqs.len(),
        r.depth.len(),
        r.confidence.len()
    );
    seqs.iter()
        .map(|s| {
            let (hd, d) = &r.depth[s];
            let (hc, c) = &r.confidence[s];
            // the depth sample's header (but for its send time)
            assert_eq!(FrameHeader { t_publish_ns: 0, ..*hc }, FrameHeader { t_publish_ns: 0, ..*hd }, "seq {s}");
            assert_eq!((hc.width, hc.height, hc.seq), (320, 240, *s));
            assert_eq!(c.len(), d.len());
            assert_eq!(c.len(), 320 * 240);
            assert!(c.iter().all(|v| (0.0..=1.0).contains(v)), "seq {s}: a confidence outside [0, 1] (or NaN)");
            (hd, d.as_slice(), c.as_slice())
        })
        .collect()
}

fn abs_rel(v: &Value) -> f64 {
    v["abs_rel"].as_f64().unwrap()
}

#[test]
fn confidence_is_published_with_depth_and_ranks_its_error_against_the_truth() {
    let (r, echo) = run("plain", &["--confidence"], true);
    let echo = echo.unwrap();
    assert_eq!(echo["received"], 5, "abvs echo confidence: {echo}");
    assert_eq!(echo["malformed"], 0, "{echo}");
    let frames = matched(&r);
    // the confidence says something: neither all zero nor all one, and most valid depth is confident
    let (mut valid, mut confident, mut zero) = (0usize, 0usize, 0usize);
    for (_, d, c) in &frames {
        for (d, c) in d.iter().zip(*c) {
            valid += d.is_finite() as usize;
            confident += (d.is_finite() && *c > 0.8) as usize;
            zero += (*c == 0.0) as usize;
        }
    }
    let n = frames.len() * 320 * 240;
    println!(
        "{} frames: valid depth {valid}, of it confident {confident}; confidence 0 at {zero} of {n}",
        frames.len()
    );
    assert!(confident as f64 > 0.4 * valid as f64 && (confident as f64) < 0.98 * valid as f64);
    assert!(zero > 0 && zero < n / 2);
    // against the truth: the confident points are the more accurate ones
    let by = &r.stats["depth_error_by_confidence"];
    let (hi, lo) = (abs_rel(&by["above"]), abs_rel(&by["at_most"]));
    println!("depth abs_rel vs truth: confidence > 0.8 {hi:.4}, <= 0.8 {lo:.4}; {by}");
    assert!(by["above"]["points"].as_u64().unwrap() > 1000 && by["at_most"]["points"].as_u64().unwrap() > 1000);
    assert!(hi < 0.75 * lo, "confident points' error {hi} is not clearly below the others' {lo}");
    assert_eq!(r.stats["publish"]["confidence"]["published"], 50, "{}", r.stats["publish"]);
}

#[test]
fn with_the_lr_check_confidence_is_zero_exactly_where_the_check_dropped_depth() {
    let (r, _) = run("lr", &["--confidence", "--lr-check"], false);
    let frames = matched(&r);
    for (h, d, c) in &frames {
        for (i, (d, c)) in d.iter().zip(*c).enumerate() {
            // a pixel without confidence lost its disparity, so its depth; every depth pixel passed the check
            assert!(*c > 0.0 || d.is_nan(), "seq {} pixel {i}: depth {d} with confidence 0", h.seq);
        }
    }
    // without either flag: census-refine's own confidence published (no second run), and more (less
    // accurate) depth
    let (plain, _) = run("none", &[], false);
    assert!(!plain.confidence.is_empty() && plain.depth.len() >= 25);
    assert_eq!(plain.stats["publish"]["confidence"]["published"], 50, "{}", plain.stats["publish"]);
    let (e, p) = (&r.stats["depth_error"], &plain.stats["depth_error"]);
    println!("depth error with the left-right check {e}, without {p}");
    let valid = |v: &Value| v["valid_fraction"].as_f64().unwrap();
    assert!(valid(e) > 0.5 * valid(p) && valid(e) < valid(p), "the check dropped no depth, or most: {e} vs {p}");
    assert!(abs_rel(e) < abs_rel(p), "the check did not make the depth more accurate: {e} vs {p}");
}
