//! The gaze service can be turned off (`--no-gaze`, `[gaze] enabled = false`) for the paired benchmark of
//! its cost (scripts/bench_gaze_cost.sh), and costs a replay with no goals almost nothing:
//! - off, the lossless depth is bit-identical to on (no goals), and no gaze statistics or services exist;
//! - on, the service's own CPU time (the gaze stage's and the iceoryx2 goal/state bridge's thread clocks, the
//!   runtime's accounting) is under 2 % of the process's CPU per frame, in the same run (CPU, not wall time:
//!   the machine's load scales both);
//! - refused by name where it cannot be off: the simulated head (lockstep with the gaze stage), Zenoh goals.
use std::path::Path;
use std::process::Command;

use serde_json::Value;

fn run(dir: &Path, name: &str, extra: &[&str]) -> Value {
    let json = dir.join(name);
    let prefix = format!("abvs-test-gazecost-{}-{name}", std::process::id());
    let o = Command::new(env!("CARGO_BIN_EXE_abvs"))
        .args(["run", "--lossless", "--frames", "10", "--resolution", "320x240", "--engine", "sgbm"])
        .args(["--no-self-check", "--truth-stride", "0", "--quiet", "--service-prefix", &prefix])
        .args(extra)
        .arg("--stats-json")
        .arg(&json)
        .output()
        .expect("run abvs");
    assert!(o.status.success(), "abvs run {extra:?}: {}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap()
}

#[test]
fn the_gaze_service_off_leaves_the_depth_bit_identical_and_on_costs_under_two_percent() {
    let t0 = std::time::Instant::now();
    let d = tempfile::tempdir().unwrap();
    let on = run(d.path(), "on.json", &[]);
    let off = run(d.path(), "off.json", &["--no-gaze"]);
    assert_eq!(on["output_digest"], off["output_digest"], "the depth must not depend on the switch");
    assert_eq!(on["frames_published"].as_u64(), Some(10), "{on}");
    assert_eq!(on["gaze"]["goals"].as_u64(), Some(0), "{on}");
    for k in ["gaze", "gaze_cpu", "gaze_iceoryx2"] {
        assert!(off.get(k).is_none(), "{k} with the gaze service off: {off}");
    }
    let stage_us = on["gaze_cpu"]["stage_us_per_frame"].as_f64().unwrap();
    let bridge_us = on["gaze_iceoryx2"]["cpu_us_per_frame"].as_f64().unwrap();
    let process_ms = on["cpu"]["ms_per_frame"].as_f64().unwrap();
    let share = (stage_us + bridge_us) * 1e-3 / process_ms;
    eprintln!(
        "gaze service: stage {stage_us:.1} us + iceoryx2 {bridge_us:.1} us per frame of {process_ms:.2} ms: {:.3} %",
        share * 100.0
    );
    assert!(share > 0.0 && share < 0.02, "the gaze service takes {:.2} % of the CPU per frame", share * 100.0);

    // where the switch cannot be off, it says so by name before any work
    let refuse = |args: &[&str], field: &str| {
        let o = Command::new(env!("CARGO_BIN_EXE_abvs")).args(args).output().unwrap();
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && e.contains(field), "{args:?}: {e}");
    };
    refuse(&["run", "--source", "sim", "--no-gaze", "--frames", "1"], "gaze.enabled");
    refuse(&["run", "--no-gaze", "--zenoh-gaze-goals", "--zenoh-insecure", "--frames", "1"], "accept_gaze_goals");
    eprintln!("test wall time {:.1} s", t0.elapsed().as_secs_f64());
}
