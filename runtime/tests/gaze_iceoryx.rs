//! A Python process using only `abvs_iceoryx2` points the eyes of a running runtime and reads the state back:
//! the fixture replayed (paced, looping) with the iceoryx2 bridge on a unique prefix; `abvs_check.py gaze`
//! waits for the runtime's states, sends look_at and prints the state that reports its goal. A replay has no
//! drive board, so the goal comes back refused by name (`no_board`), with the measured fixation of the
//! replayed encoders; the Rust handle's goals take the same path (counted in the stats JSON's `gaze`).
use std::process::Command;
use std::time::{Duration, Instant};

use abvs_runtime::shipped::shipped;
use abvs_runtime::Runtime;
use abvs_runtime_core::config::{EngineKind, RuntimeConfig};
use abvs_runtime_core::gaze::{Phase, Refusal};

#[path = "../../tests/support/python_env.rs"]
mod python_env;
use python_env::{python, repo};

#[test]
fn a_python_process_sends_a_goal_and_reads_the_state() {
    let t0 = Instant::now();
    let mut c = RuntimeConfig::for_session(shipped("fixtures/session"));
    c.disparity.width = 160;
    c.disparity.height = 120;
    c.disparity.engine = EngineKind::Sgbm;
    c.source.looping = true;
    c.source.seconds = Some(60.0);
    c.sinks.self_check.enabled = false;
    let prefix = format!("abvs-test-gaze-{}", std::process::id());
    c.bridges.iceoryx.service_prefix = prefix.clone();
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("stats.json");
    c.sinks.stats_json = Some(json.clone());
    let handle = Runtime::from_config(&c).unwrap().spawn().unwrap();

    let o = Command::new(python())
        .arg(repo().join("python/tests/abvs_check.py"))
        .args(["gaze", &prefix, "0.1", "-0.05", "0.8"])
        .output()
        .expect("running python");
    assert!(o.status.success(), "python: {}", String::from_utf8_lossy(&o.stderr));
    let out = String::from_utf8_lossy(&o.stdout);
    let v: serde_json::Value = serde_json::from_str(out.lines().last().unwrap()).expect("python prints JSON");
    eprintln!("{v}");
    assert_eq!(v["before"]["phase"], "idle", "{v}");
    let s = &v["state"];
    assert_eq!(s["goal_id"], v["goal"], "{v}");
    assert_eq!((s["phase"].as_str(), s["reason"].as_str()), (Some("refused"), Some("no_board")), "{v}");
    assert!(s["commanded_fixation"][0].is_null(), "{v}");
    // the measured fixation of the replayed eyes: a point where the axes meet, or none (null)
    assert_eq!(s["measured_fixation"].as_array().map(Vec::len), Some(3), "{v}");

    // the Rust handle: same mailbox, same refusal
    let gaze = handle.gaze();
    let id = gaze.look_at([0.0, 0.0, 1.0]);
    let t = Instant::now();
    while gaze.state().is_none_or(|s| s.goal_id != id) {
        assert!(t.elapsed() < Duration::from_secs(30), "the goal was not taken: {:?}", gaze.state());
        std::thread::sleep(Duration::from_millis(5));
    }
    let st = gaze.state().unwrap();
    assert_eq!((st.phase, st.reason), (Phase::Refused, Some(Refusal::NoBoard)));
    handle.stop();
    let report = handle.join().unwrap();
    let j = report.json();
    assert_eq!(j["gaze"]["goals"], 2, "{}", j["gaze"]);
    assert_eq!(j["gaze"]["refused"]["no_board"], 2, "{}", j["gaze"]);
    assert_eq!(j["gaze"]["frames_gated_saccade"], 0);
    assert_eq!(j["gaze_iceoryx2"]["goals_received"], 1, "{j}");
    let states = &j["gaze_iceoryx2"];
    assert_eq!(
        states["states_published"].as_u64().unwrap() + states["failures"].as_u64().unwrap(),
        report.stats.frames_published,
        "one state per published frame: {j}"
    );
    eprintln!("test wall time {:.1} s", t0.elapsed().as_secs_f64());
}
