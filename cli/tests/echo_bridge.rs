//! `abvs echo` against the real iceoryx2 bridge: this test publishes synthetic clouds at ~30 Hz while a real
//! `abvs echo cloud --count 20 --json` process and a crashing subscriber (`--abort-after 3`) run; then a new
//! echo starts after the crash.
use std::os::unix::process::ExitStatusExt;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use abvs_runtime::bridges::iceoryx::{dead_node_pids, BridgeConfig, CloudPoint, CloudPublisher, FrameHeader};
use abvs_runtime_core::messages::monotonic_ns;

fn echo(prefix: &str, extra: &[&str]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_abvs"))
        .args(["echo", "cloud", "--prefix", prefix, "--timeout-s", "30"])
        .args(extra)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn abvs echo")
}

struct Pub {
    p: CloudPublisher,
    seq: u64,
    calls: u64,
}

impl Pub {
    /// One synthetic cloud; asserts the publish call returned Ok.
    fn send(&mut self) {
        let mut h = FrameHeader::new_left_home();
        h.seq = self.seq;
        h.t_frame_ns = monotonic_ns() - 2_000_000; // as if exposed 2 ms ago
        h.width = 320;
        h.height = 240;
        h.baseline_m = 0.065;
        let n = 2000 + (self.seq as usize % 5) * 100;
        let r = self.p.publish_cloud(&h, n, |pts| {
            for i in 0..n {
                pts.push(CloudPoint { x: i as f32 * 1e-3, y: 0.0, z: 1.0, rgba: 0xFFFF_FFFF });
            }
        });
        assert!(r.is_ok(), "publish {} failed: {r:?}", self.seq);
        self.seq += 1;
        self.calls += 1;
    }

    /// Publishes at ~30 Hz until every child has exited (or 60 s passed); returns their outputs.
    fn run_until_exit(&mut self, mut children: Vec<Child>) -> Vec<std::process::Output> {
        let t0 = Instant::now();
        let mut done = vec![false; children.len()];
        while done.iter().any(|d| !d) {
            assert!(t0.elapsed() < Duration::from_secs(60), "children did not finish in 60 s");
            self.send();
            for (c, d) in children.iter_mut().zip(done.iter_mut()) {
                if !*d && c.try_wait().unwrap().is_some() {
                    *d = true;
                }
            }
            std::thread::sleep(Duration::from_millis(33));
        }
        children.into_iter().map(|c| c.wait_with_output().unwrap()).collect()
    }
}

fn check_echo_json(out: &std::process::Output, count: u64) -> serde_json::Value {
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "echo failed: {:?}\nstdout: {stdout}\nstderr: {}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    let lines: Vec<&str> = stdout.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "exactly one JSON object on stdout: {stdout}");
    let v: serde_json::Value = serde_json::from_str(lines[0]).expect("JSON");
    eprintln!("echo --count {count}: {v}");
    assert_eq!(v["received"].as_u64(), Some(count), "{v}");
    let fps = v["fps"].as_f64().unwrap();
    assert!((8.0..=60.0).contains(&fps), "fps {fps} not near the 30 Hz published: {v}");
    let (p50, p99) = (v["latency_ms"]["p50"].as_f64().unwrap(), v["latency_ms"]["p99"].as_f64().unwrap());
    assert!((2.0..250.0).contains(&p50), "latency p50 {p50} ms: {v}");
    assert!(p99 >= p50 && p99 < 3000.0, "latency p99 {p99} ms: {v}");
    let pm = v["points_mean"].as_f64().unwrap();
    assert!((2000.0..=2400.0).contains(&pm), "points_mean {pm}: {v}");
    v
}

#[test]
fn echo_counts_clouds_while_a_subscriber_crashes_and_a_new_one_starts() {
    let prefix = format!("abvs-clitest-{}", std::process::id());
    let cfg = BridgeConfig::for_resolution(320, 240).with_prefix(prefix.clone());
    let mut p = Pub { p: CloudPublisher::new(&cfg).expect("publisher"), seq: 0, calls: 0 };

    let crasher = echo(&prefix, &["--abort-after", "3"]);
    let crashed_pid = crasher.id();
    let outs = p.run_until_exit(vec![echo(&prefix, &["--count", "20", "--json"]), crasher]);
    check_echo_json(&outs[0], 20);
    let crashed = &outs[1];
    assert_eq!(
        crashed.status.signal(),
        Some(libc_sigabrt()),
        "the crashing subscriber died by SIGABRT: {:?}",
        crashed.status
    );

    // the crashed process still holds a borrowed sample and its buffer; publishing goes on regardless and
    // its resources are removed
    // (whichever node is created or dropped first cleans it: the other echo's exit may have done it already)
    p.p.cleanup_dead_nodes();
    let dead = dead_node_pids().unwrap();
    assert!(!dead.contains(&(crashed_pid as i32)), "the crashed echo's node is cleaned up: dead {dead:?}");

    // a new subscriber after the crash
    let outs = p.run_until_exit(vec![echo(&prefix, &["--count", "5", "--json"])]);
    check_echo_json(&outs[0], 5);

    let s = p.p.stats();
    assert_eq!(s.published, p.calls, "every publish call sent its sample: {s:?}");
    assert_eq!(s.loan_failures, 0, "{s:?}");
}

#[test]
fn echo_fails_clearly_when_nothing_arrives() {
    let prefix = format!("abvs-clitest-empty-{}", std::process::id());
    let out = Command::new(env!("CARGO_BIN_EXE_abvs"))
        .args(["echo", "depth", "--prefix", &prefix, "--timeout-s", "0.5", "--json"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no sample on") && err.contains(&format!("{prefix}/depth")), "{err}");
}

fn libc_sigabrt() -> i32 {
    6
}
