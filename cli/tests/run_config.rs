//! The runtime configuration file: `--print-config` reproduces the run it describes, unknown
//! fields are refused with file and line, and the shipped examples load.
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn abvs(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_abvs")).args(args).output().expect("run abvs")
}

fn ok(args: &[&str]) -> String {
    let o = abvs(args);
    assert!(o.status.success(), "abvs {args:?} failed:\n{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn digest(stats: &Path) -> String {
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(stats).unwrap()).unwrap();
    v["output_digest"].as_str().expect("output_digest").to_string()
}

/// `abvs run --print-config > f.toml && abvs run --config f.toml --lossless` is `abvs run
/// --lossless` (same output_digest), with the default engine.
#[test]
fn printed_config_reproduces_the_run() {
    let d = tempfile::tempdir().unwrap();
    let printed = ok(&["run", "--print-config"]);
    assert!(
        printed.contains("format = \"abvs-runtime/1\"") && printed.contains("engine = \"census-refine\""),
        "{printed}"
    );
    let f = d.path().join("f.toml");
    std::fs::write(&f, &printed).unwrap();
    let (a, b) = (d.path().join("a.json"), d.path().join("b.json"));
    let common = ["--lossless", "--frames", "12", "--no-publish", "--quiet", "--stats-json"];
    let mut with_file = vec!["run", "--config", f.to_str().unwrap()];
    with_file.extend(common);
    with_file.push(a.to_str().unwrap());
    ok(&with_file);
    let mut plain = vec!["run"];
    plain.extend(common);
    plain.push(b.to_str().unwrap());
    ok(&plain);
    assert_eq!(digest(&a), digest(&b));
    // A flag overrides the file: another engine, another output.
    let c = d.path().join("c.json");
    let (fs, cs) = (f.to_str().unwrap(), c.to_str().unwrap());
    ok(&[
        "run",
        "--config",
        fs,
        "--engine",
        "sgbm",
        "--lossless",
        "--frames",
        "12",
        "--no-publish",
        "--quiet",
        "--stats-json",
        cs,
    ]);
    assert_ne!(digest(&a), digest(&c));
}

#[test]
fn unknown_field_is_refused_with_file_and_line() {
    let d = tempfile::tempdir().unwrap();
    let printed = ok(&["run", "--print-config"]);
    let bad = printed.replace("[disparity]\n", "[disparity]\nmax_disparity = 96\n");
    let line = bad.lines().position(|l| l.starts_with("max_disparity")).unwrap() + 1;
    let f = d.path().join("bad.toml");
    std::fs::write(&f, bad).unwrap();
    let o = abvs(&["run", "--config", f.to_str().unwrap()]);
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains(&format!("bad.toml:{line}")) && e.contains("max_disparity"), "{e}");
    // A missing file is named too.
    let o = abvs(&["run", "--config", "/nonexistent/robot.toml"]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("/nonexistent/robot.toml"));
}

/// The shipped examples: the fixture's is the default run; the live one describes the devices.
#[test]
fn shipped_examples_load() {
    let fixture = repo().join("config/fixture.toml");
    let live = repo().join("config/live.toml");
    let a = ok(&["run", "--config", fixture.to_str().unwrap(), "--print-config"]);
    let b = ok(&["run", "--print-config"]);
    let norm = |s: &str| {
        s.replace(&std::fs::canonicalize(repo().join("fixtures/session")).unwrap().display().to_string(), "S")
    };
    let canon = |s: String| {
        // Both name the fixture session, by different spellings of its path.
        let v: toml::Value = toml::from_str(&s).unwrap();
        let p = v["source"]["session"].as_str().unwrap().to_string();
        let c = std::fs::canonicalize(&p).unwrap().display().to_string();
        norm(&s.replace(&p, &c))
    };
    assert_eq!(canon(a), canon(b));
    let l = ok(&["run", "--config", live.to_str().unwrap(), "--print-config"]);
    assert!(l.contains("kind = \"live\"") && l.contains("/dev/ttyACM0"), "{l}");
}

/// The left-right check's fields: printed with their defaults, set by the flags, read back from a file.
#[test]
fn print_config_carries_the_confidence_and_the_left_right_check() {
    let plain = ok(&["run", "--print-config"]);
    let v: toml::Value = toml::from_str(&plain).unwrap();
    let d = &v["disparity"];
    assert_eq!((d["confidence"].as_bool(), d["lr_check"].as_bool()), (Some(false), Some(false)), "{plain}");
    assert_eq!(d["lr_max_diff"].as_float(), Some(1.0), "{plain}");
    let on = ok(&["run", "--print-config", "--confidence", "--lr-check"]);
    let v: toml::Value = toml::from_str(&on).unwrap();
    assert_eq!(
        (v["disparity"]["confidence"].as_bool(), v["disparity"]["lr_check"].as_bool()),
        (Some(true), Some(true))
    );
    // a file's values come back, and a flag adds to them
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("c.toml");
    std::fs::write(
        &f,
        plain.replace("lr_max_diff = 1.0", "lr_max_diff = 2.5").replace("lr_check = false", "lr_check = true"),
    )
    .unwrap();
    let back = ok(&["run", "--config", f.to_str().unwrap(), "--print-config", "--confidence"]);
    let v: toml::Value = toml::from_str(&back).unwrap();
    let d = &v["disparity"];
    assert_eq!(
        (d["confidence"].as_bool(), d["lr_check"].as_bool(), d["lr_max_diff"].as_float()),
        (Some(true), Some(true), Some(2.5))
    );
    // out of range is refused, naming the field
    std::fs::write(&f, plain.replace("lr_max_diff = 1.0", "lr_max_diff = -1.0")).unwrap();
    let o = abvs(&["run", "--config", f.to_str().unwrap(), "--print-config"]);
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("lr_max_diff"));
}
