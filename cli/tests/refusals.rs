//! The doors of issue 26, each run for real: bad numbers refused before any work, empty data
//! never scored as perfect, models checked against their manifests' hashes, outputs checked at
//! the start, values outside the physics refused, help that lists what is accepted.
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

fn abvs(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_abvs")).args(args).output().expect("run abvs")
}

fn ok(args: &[&str]) -> String {
    let o = abvs(args);
    assert!(o.status.success(), "abvs {args:?} failed:\n{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned() + &String::from_utf8_lossy(&o.stderr)
}

/// Refused quickly, exit non-zero, stderr containing every one of `want`; returns stderr.
fn refused(args: &[&str], want: &[&str]) -> String {
    let t0 = Instant::now();
    let o = abvs(args);
    let e = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(!o.status.success(), "abvs {args:?} was accepted:\n{e}");
    assert_ne!(o.status.code(), Some(101), "abvs {args:?} panicked:\n{e}");
    assert!(o.status.code().is_some(), "abvs {args:?} died of a signal:\n{e}");
    for w in want {
        assert!(e.contains(w), "abvs {args:?}: no '{w}' in:\n{e}");
    }
    assert!(t0.elapsed() < Duration::from_secs(20), "abvs {args:?} took {:?} to refuse", t0.elapsed());
    e
}

fn s(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// A 5^3 dataset of the embedded unit C0 and an mh model fitted on it.
fn dataset_and_model(d: &Path) -> (PathBuf, PathBuf) {
    let data = d.join("a.csv");
    let unit = repo().join("fixtures/units/c0.toml");
    ok(&["sim", "dataset", "--unit", &s(&unit), "--grid-n", "5", "--dropout", "0", "--out", &s(&data)]);
    let model = d.join("mh");
    ok(&["calib", "fit", "--method", "mh", "--train", &s(&data), "--val", &s(&data), "--out", &s(&model)]);
    (data, model)
}

#[test]
fn numeric_arguments_are_refused_where_they_are_parsed() {
    let t = tempfile::tempdir().unwrap();
    let out = s(&t.path().join("o.csv"));
    refused(&["kin", "psc", "--step-deg", "0", "--out", &out], &["--step-deg", "(0, 30]"]);
    refused(&["kin", "psc", "--step-deg=-1", "--out", &out], &["--step-deg"]);
    refused(&["kin", "psc", "--step-deg", "NaN", "--out", &out], &["--step-deg"]);
    // in range, but a grid no machine holds / that runs for minutes: refused by its size
    refused(&["kin", "psc", "--step-deg=1e-9", "--out", &out], &["--step-deg", "poses"]);
    refused(&["kin", "psc", "--step-deg=0.001", "--out", &out], &["--step-deg", "poses"]);
    let unit = s(&repo().join("fixtures/units/c0.toml"));
    refused(&["sim", "dataset", "--unit", &unit, "--grid-n", "100000", "--out", &out], &["--grid-n", "[2, 125]"]);
    refused(&["sim", "dataset", "--unit", &unit, "--step-deg=1e-9", "--out", &out], &["--step-deg", "poses"]);
    refused(&["sim", "dataset", "--unit", &unit, "--step-deg=-3", "--out", &out], &["--step-deg"]);
    refused(&["sim", "dataset", "--unit", &unit, "--out", &out], &["--step-deg", "--grid-n"]);
    refused(
        &["sim", "dataset", "--unit", &unit, "--step-deg", "3", "--gravity", "0,0,0", "--out", &out],
        &["--gravity"],
    );
    refused(&["sim", "dataset", "--unit", &unit, "--step-deg", "3", "--range", "30,0,30", "--out", &out], &["--range"]);
    let m = s(&t.path().join("m"));
    refused(&["calib", "fit", "--method", "m1", "--train", &out, "--out", &m, "--hidden", "0"], &["--hidden"]);
    refused(&["calib", "fit", "--method", "m1", "--train", &out, "--out", &m, "--lr", "inf"], &["--lr"]);
    refused(&["calib", "fit", "--method", "m1f", "--train", &out, "--out", &m], &["--method", "mh, m1, m2, hybrid"]);
    refused(&["echo", "depth", "--timeout-s", "1e30"], &["--timeout-s"]);
    refused(&["echo", "depth", "--timeout-s", "0"], &["--timeout-s"]);
    refused(&["run", "--frames", "0"], &["--frames"]);
    refused(&["run", "--seconds", "1e30"], &["--seconds"]);
    let png = s(&t.path().join("x.png"));
    refused(&["disparity", "--left", &png, "--right", &png, "--out", &out, "--lr-max-diff=-1"], &["--lr-max-diff"]);
    let calib = s(&repo().join("fixtures/session/calib"));
    refused(&["gaze", "fixate", "--calib", &calib, "--point", "0,0,1", "--gravity", "0,0,0"], &["--gravity", "unit"]);
    refused(&["gaze", "fixate", "--calib", &calib, "--point", "0,0,1", "--gravity", "0,2,0"], &["--gravity"]);
    refused(
        &["gaze", "fixate", "--calib", &calib, "--pixel", "1,1", "--depth", "1", "--left-theta", "0,90,0"],
        &["--left-theta", "[-89, 89]"],
    );
}

#[test]
fn outputs_are_checked_before_the_run() {
    let t = tempfile::tempdir().unwrap();
    let missing = s(&t.path().join("no/such/dir/stats.json"));
    // refused at once, not after the run (the embedded session would take many seconds in a debug build)
    refused(&["run", "--stats-json", &missing], &["--stats-json", "does not exist"]);
    let file = t.path().join("f");
    std::fs::write(&file, "").unwrap();
    refused(&["run", "--dump", &s(&file.join("d"))], &["--dump"]);
    refused(&["run", "--self-check-log", &s(t.path())], &["--self-check-log", "is a directory"]);
}

#[test]
fn empty_data_is_an_error_never_a_perfect_score() {
    let t = tempfile::tempdir().unwrap();
    let (data, model) = dataset_and_model(t.path());
    let header = std::fs::read_to_string(&data).unwrap().lines().next().unwrap().to_string() + "\n";
    let empty = t.path().join("empty.csv");
    std::fs::write(&empty, &header).unwrap();
    refused(&["calib", "eval", "--model", &s(&model), "--data", &s(&empty)], &["no samples"]);
    refused(
        &[
            "calib",
            "fit",
            "--method",
            "mh",
            "--train",
            &s(&data),
            "--val",
            &s(&empty),
            "--out",
            &s(&t.path().join("v")),
        ],
        &["--val", "no samples"],
    );
    let th = t.path().join("th.csv");
    std::fs::write(&th, "theta1_deg,theta2_deg,theta3_deg\n").unwrap();
    refused(&["kin", "fk", "--in", &s(&th), "--out", &s(&t.path().join("p.csv"))], &["no rows"]);
}

#[test]
fn models_are_verified_validated_and_replaced_whole() {
    let t = tempfile::tempdir().unwrap();
    let (data, model) = dataset_and_model(t.path());
    // validation metrics for a physics method, from the --val given
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(model.join("manifest.json")).unwrap()).unwrap();
    assert!(m["validation"]["mse_total"].as_f64().is_some(), "{m}");
    assert!(m["training"]["range_deg"].is_array(), "{m}");
    assert!(m["sha256"]["unit.toml"].is_string(), "{m}");
    // --out over an existing model: refused, or replaced whole with --force
    let args = ["calib", "fit", "--method", "mh", "--train", &s(&data), "--out", &s(&model)];
    refused(&args, &["--out", "--force"]);
    std::fs::write(model.join("residual.onnx"), "stale").unwrap();
    ok(&[&args[..], &["--force"]].concat());
    assert!(!model.join("residual.onnx").exists(), "the old network is left beside the new manifest");
    ok(&["calib", "eval", "--model", &s(&model), "--data", &s(&data)]);
    // a changed file is refused, naming it and both hashes
    let u = model.join("unit.toml");
    let text = std::fs::read_to_string(&u).unwrap();
    std::fs::write(&u, text.replacen("= 0.", "= 1.", 1)).unwrap();
    let want = m["sha256"]["unit.toml"].as_str().unwrap().to_string();
    let e = refused(&["calib", "eval", "--model", &s(&model), "--data", &s(&data)], &["unit.toml", "SHA-256"]);
    assert!(e.contains("manifest.json"), "{e}");
    let _ = want;
}

#[test]
fn a_damaged_disparity_model_is_refused_with_both_hashes() {
    let t = tempfile::tempdir().unwrap();
    let dir = t.path().join("hitnet-s");
    std::fs::create_dir(&dir).unwrap();
    let src = repo().join("models/hitnet/hitnet-s");
    for f in ["manifest.json", "model.onnx"] {
        std::fs::copy(src.join(f), dir.join(f)).unwrap();
    }
    let mut b = std::fs::read(dir.join("model.onnx")).unwrap();
    let n = b.len();
    b[n - 100] ^= 0x01;
    b[n - 200] ^= 0x01;
    std::fs::write(dir.join("model.onnx"), b).unwrap();
    let expected = "fa869547d5e11d2a56d1b9695faf4d82420602c413914414cdcdcacb2fb2ffde";
    refused(
        &["run", "--resolution", "320x240", "--model", &s(&dir), "--frames", "1", "--no-publish", "--quiet"],
        &["model.onnx", "SHA-256", expected],
    );
}

#[test]
fn ik_targets_outside_the_calibrated_workspace_and_bad_gravity_rows_are_refused() {
    let t = tempfile::tempdir().unwrap();
    let (_, model) = dataset_and_model(t.path());
    let targets = t.path().join("t.csv");
    std::fs::write(&targets, "alpha_deg,beta_deg,gamma_deg,gx,gy,gz\n5,2,-5,0,1,0\n45,0,0,0,1,0\n0,0,0,0,0,0\n")
        .unwrap();
    let out = t.path().join("o.csv");
    let e = refused(
        &["calib", "ik", "--model", &s(&model), "--in", &s(&targets), "--out", &s(&out)],
        &["t.csv:3", "outside the calibrated workspace", "t.csv:4", "unit vector"],
    );
    assert!(!e.contains("t.csv:2"), "{e}");
}

#[test]
fn help_lists_what_is_accepted_and_messages_say_what_the_file_holds() {
    let h = ok(&["run", "--help"]);
    assert!(h.contains("fused"), "{h}");
    let f = ok(&["calib", "fit", "--help"]);
    assert!(f.contains("[possible values: mh, m1, m2, hybrid]"), "{f}");
    let u = tempfile::tempdir().unwrap();
    let p = u.path().join("u.toml");
    let text = std::fs::read_to_string(repo().join("fixtures/units/c0.toml")).unwrap();
    std::fs::write(&p, text.replace("d1_deg = 60.0", "d1_deg = -60.0")).unwrap();
    let th = u.path().join("th.csv");
    std::fs::write(&th, "theta1_deg,theta2_deg,theta3_deg\n0,0,0\n").unwrap();
    let e = refused(
        &["kin", "fk", "--in", &s(&th), "--out", &s(&u.path().join("o.csv")), "--unit", &s(&p)],
        &["geometry.d1_deg", "-60"],
    );
    assert!(!e.contains("-120"), "{e}");
}

/// `sim session --out` into a session already there: refused without --force (a render over it would
/// leave its extra frames behind); with --force the old session is removed first, so only the new frames
/// are there, and files that are not the session's stay.
#[test]
fn sim_session_refuses_an_existing_directory_and_force_leaves_no_stale_frames() {
    let t = tempfile::tempdir().unwrap();
    let out = t.path().join("s");
    let render = |frames: &str, extra: &[&str]| {
        let mut a = vec!["sim", "session", "--out", out.to_str().unwrap(), "--frames", frames, "--width", "64"];
        a.extend(["--height", "48", "--supersample", "1", "--fk-method", "mh", "--calib-step-deg", "20"]);
        a.extend(extra);
        a.into_iter().map(String::from).collect::<Vec<_>>()
    };
    fn args(v: &[String]) -> Vec<&str> {
        v.iter().map(String::as_str).collect()
    }
    ok(&args(&render("4", &[])));
    let count = || std::fs::read_dir(out.join("frames")).unwrap().count();
    assert_eq!(count(), 8);
    std::fs::write(out.join("notes.txt"), "mine").unwrap();
    let e = refused(&args(&render("2", &[])), &["--out", "--force"]);
    assert!(e.contains("not empty"), "{e}");
    assert_eq!(count(), 8, "a refusal touches nothing");
    ok(&args(&render("2", &["--force"])));
    assert_eq!(count(), 4, "2 frames of 2 eyes: none of the 4-frame session's left");
    let csv = std::fs::read_to_string(out.join("frames.csv")).unwrap();
    assert_eq!(csv.lines().count(), 3, "{csv}");
    assert_eq!(std::fs::read_to_string(out.join("notes.txt")).unwrap(), "mine");
    // an empty directory is a new one
    let empty = t.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    ok(&["--validate-only", "sim", "session", "--out", empty.to_str().unwrap()]);
}

/// `sim session --fixation-m NEAR..FAR` (issue 38: the gaze plan's target depths): refused by name unless
/// 0.2 <= NEAR < FAR <= 5 m; a usable range passes the checks before any rendering.
#[test]
fn sim_session_fixation_depths_are_checked() {
    let t = tempfile::tempdir().unwrap();
    let out = t.path().join("s");
    let out = out.to_str().unwrap();
    for bad in ["2..1", "0.1..1", "1..9", "0.5", "0.5..NaN", "a..b"] {
        refused(&["sim", "session", "--out", out, "--fixation-m", bad], &["--fixation-m"]);
    }
    ok(&["--validate-only", "sim", "session", "--out", out, "--fixation-m", "0.5..2"]);
    assert!(!t.path().join("s").join("frames").exists(), "validation renders nothing");
}
