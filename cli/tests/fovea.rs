//! The fovea end to end through the `abvs` binary on the fixture session (800x600 frames): scored against the
//! truth next to the main map over the same rays, and the main map bit-identical with the fovea off.
use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/session")
}

/// `abvs run --lossless` of the fixture's first frames at 320x240 (SGBM) with `extra`; its stats JSON.
fn run(extra: &[&str]) -> Value {
    let dir = tempfile::tempdir().unwrap();
    let stats = dir.path().join("stats.json");
    let out = Command::new(env!("CARGO_BIN_EXE_abvs"))
        .args(["run", "--quiet", "--no-publish", "--no-self-check", "--lossless", "--engine", "sgbm"])
        .args(["--resolution", "320x240", "--frames", "8", "--session"])
        .arg(fixture())
        .arg("--stats-json")
        .arg(&stats)
        .args(extra)
        .output()
        .unwrap();
    assert!(out.status.success(), "abvs run {extra:?}: {}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap()
}

fn err(v: &Value, key: &str) -> (f64, f64, f64) {
    let e = &v[key];
    let f = |k: &str| e[k].as_f64().unwrap_or_else(|| panic!("{key}.{k}: {e}"));
    (f("abs_rel"), f("point_mm_p50"), f("valid"))
}

#[test]
fn the_fovea_beats_the_main_map_over_the_same_rays_and_leaves_the_main_map_as_it_was() {
    let on = run(&[]);
    let off = run(&["--fovea", "off"]);
    // the main map is the same bit for bit; only the fovea's outputs are added
    assert_eq!(on["output_digest"], off["output_digest"]);
    assert_eq!(on["frames_published"], 8);
    assert!(off.get("fovea").is_none() && off.get("depth_error_fovea").is_none(), "{off:#}");
    assert!(off["stages"].get("fovea").is_none());
    let f = &on["fovea"];
    assert_eq!(f["frames"], 8, "{f}");
    assert_eq!(f["window"], serde_json::json!([320, 240]));
    // the fixture's eyes verge on the scene: every frame's window is on a measured fixation, searched from
    // the main map's answer
    assert_eq!(f["measured_fixation"], 8, "{f}");
    assert_eq!(f["range_from_main"], 8, "{f}");
    assert!(on["stages"]["fovea"]["p50"].as_f64().unwrap() > 0.0);
    assert!(on["cpu"]["lanes_ms_per_frame"]["fovea"].as_f64().unwrap() > 0.0, "{}", on["cpu"]);
    let (fov, main) = (err(&on, "depth_error_fovea"), err(&on, "depth_error_fovea_main"));
    eprintln!("abs_rel / point_mm_p50 / valid: fovea {fov:?}, main map over the same rays {main:?}");
    // at the raw frames' scale (f 392 px against the main map's 134 px) the fovea's points are closer
    assert!(fov.0 < 0.03 && fov.2 > 0.7, "fovea {fov:?}");
    assert!(fov.1 < 0.6 * main.1 && fov.0 < main.0, "fovea {fov:?} vs main {main:?}");
    // where the narrow search has no answer the main map's stands: never sparser than the main map there
    assert!(fov.2 >= main.2, "valid: fovea {fov:?} vs main {main:?}");
    let filled = f["filled_from_main_fraction"].as_f64().unwrap();
    assert!((0.0..0.5).contains(&filled), "{f}");
    // a smaller window: its own size, the same main map
    let small = run(&["--fovea", "160x120"]);
    assert_eq!(small["fovea"]["window"], serde_json::json!([160, 120]));
    assert_eq!(small["output_digest"], off["output_digest"]);
}

#[test]
fn a_bad_fovea_flag_is_refused_by_name() {
    for bad in ["on", "320", "8x8", "320x0"] {
        let o = Command::new(env!("CARGO_BIN_EXE_abvs"))
            .args(["run", "--quiet", "--no-publish", "--fovea", bad, "--session"])
            .arg(fixture())
            .output()
            .unwrap();
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && e.contains("fovea"), "--fovea {bad}: {e}");
    }
}
