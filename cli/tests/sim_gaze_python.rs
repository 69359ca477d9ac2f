//! A Python process using only `abvs_iceoryx2` points the simulated eyes (issue 36, "Done when"): `abvs run
//! --source sim` (160x120, SGBM: rendering stays fast in a debug build) publishes on a unique iceoryx2
//! prefix; `python/tests/gaze_points.py` sends three look_at goals one after the other and, for each, waits
//! for a state that reports its id as `settled`, then prints them. The test checks each state's fields, then
//! stops the run (SIGTERM: it ends as at its end) and checks the same goals in the stats JSON: taken from
//! iceoryx2, settled on the true units within the bars, every saccade frame gated, no frame lost.
//!
//! The simulation runs in virtual time as fast as it renders: a goal from another process is taken at the
//! next frame the gaze stage starts, so which frame takes it depends on the machine, not the outcome.
use std::process::{Command, Stdio};
use std::time::Instant;

use serde_json::Value;

#[path = "../../tests/support/python_env.rs"]
mod python_env;
use python_env::{python, repo};

/// Points in the left home camera frame (m): near, far and off to the side, all inside the workspace.
const POINTS: [[f64; 3]; 3] = [[0.06, -0.04, 0.7], [-0.12, 0.05, 0.45], [0.1, 0.08, 1.2]];

#[test]
fn a_python_process_points_the_simulated_eyes_and_reads_each_settled_state() {
    let t0 = Instant::now();
    let d = tempfile::tempdir().unwrap();
    let json = d.path().join("stats.json");
    let prefix = format!("abvs-test-simgaze-{}", std::process::id());
    let mut abvs = Command::new(env!("CARGO_BIN_EXE_abvs"))
        .args(["run", "--source", "sim", "--seed", "5", "--width", "160", "--height", "120"])
        .args(["--resolution", "160x120", "--engine", "sgbm", "--no-self-check", "--quiet"])
        // a bound, should the script fail: the test stops the run once the script is done
        .args(["--frames", "3000", "--truth-stride", "0", "--service-prefix", &prefix])
        .arg("--sim-calib")
        .arg(d.path().join("calib"))
        .arg("--stats-json")
        .arg(&json)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start abvs");

    let points: Vec<String> = POINTS.iter().map(|p| format!("{},{},{}", p[0], p[1], p[2])).collect();
    let py = Command::new(python())
        .arg(repo().join("python/tests/gaze_points.py"))
        .arg(&prefix)
        .args(&points)
        .output()
        .expect("running python");
    // SAFETY: a plain signal to the child this test started: it stops taking frames and reports
    unsafe { libc::kill(abvs.id() as i32, libc::SIGTERM) };
    let status = abvs.wait().unwrap();
    let err = std::io::read_to_string(abvs.stderr.take().unwrap()).unwrap();
    let out = String::from_utf8_lossy(&py.stdout);
    assert!(py.status.success(), "python: {out}\n{}\nabvs: {err}", String::from_utf8_lossy(&py.stderr));
    assert!(status.success(), "abvs run --source sim: {status}\n{err}");
    let v: Value = serde_json::from_str(out.lines().last().unwrap()).expect("python prints JSON");
    eprintln!("{v}");

    // what Python read: one settled state per goal, with its id and the fields the issue names
    assert_eq!(v["first"]["phase"], "idle", "{v}");
    let goals = v["goals"].as_array().unwrap();
    assert_eq!(goals.len(), POINTS.len(), "{v}");
    let mut ids = std::collections::BTreeSet::new();
    for (g, p) in goals.iter().zip(POINTS) {
        let s = &g["state"];
        assert!(ids.insert(g["id"].as_u64().unwrap()), "ids are unique: {v}");
        assert_eq!(
            (&s["goal_id"], s["phase"].as_str(), &s["reason"]),
            (&g["id"], Some("settled"), &Value::Null),
            "{g}"
        );
        let xyz = |k: &str| -> Vec<f64> { s[k].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect() };
        // the commanded point is the goal's, to the bit
        assert_eq!(xyz("commanded_fixation"), p.to_vec(), "{g}");
        // where the encoders and calibrated FK put both optical axes: on the point (the depth along the axes is
        // the least certain: a few mm at 1.2 m from a 0.004 deg count)
        let m = xyz("measured_fixation");
        let miss = (0..3).map(|i| (m[i] - p[i]).powi(2)).sum::<f64>().sqrt();
        assert!(miss < 0.01, "measured fixation {m:?} is {miss} m from {p:?}: {g}");
        // the vergence distance: from between the optical centres (about 32.5 mm right of the left one)
        let range = ((p[0] - 0.0325).powi(2) + p[1].powi(2) + p[2].powi(2)).sqrt();
        let verg = s["vergence_m"].as_f64().unwrap();
        assert!((verg - range).abs() < 0.01, "vergence {verg} m for a point {range} m away: {g}");
        assert!(s["planned_ms"].as_f64().unwrap() > 0.0, "{g}");
    }

    // the run's own account of the same goals, scored against the head's truth
    let a: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let g = &a["gaze"];
    let n = |k: &str| g[k].as_u64().unwrap_or_else(|| panic!("gaze.{k} in {g}"));
    let f = |k: &str, q: &str| g[k][q].as_f64().unwrap_or_else(|| panic!("gaze.{k}.{q} in {g}"));
    assert_eq!(a["gaze_iceoryx2"]["goals_received"].as_u64(), Some(3), "{a}");
    assert_eq!(g["sources"]["iceoryx2"]["taken"].as_u64(), Some(3), "{g}");
    assert_eq!((n("goals"), n("accepted"), n("settled"), n("goals_unsettled")), (3, 3, 3, 0), "{g}");
    assert!(f("fixation_error_deg", "p50") <= 0.02 && f("fixation_error_deg", "max") <= 0.05, "{g}");
    assert_eq!(n("goals_settled_late"), 0, "settle time over the plan + 2 frames: {g}");
    assert_eq!((n("frames_moving_ungated"), n("seq_gaps")), (0, 0), "{g}");
    assert_eq!(a["frames_dropped"].as_u64(), Some(0), "{a}");
    eprintln!("test wall time {:.1} s ({} frames)", t0.elapsed().as_secs_f64(), a["frames_published"]);
}
