//! End-to-end tests of the `abvs` program on real files.
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

fn p(d: &Path, f: &str) -> String {
    d.join(f).to_string_lossy().into_owned()
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

#[test]
fn sim_is_reproducible_bit_for_bit_and_follows_the_protocol() {
    let d = tempfile::tempdir().unwrap();
    ok(&["sim", "unit", "--seed", "7", "--out", &p(d.path(), "u.toml")]);
    ok(&["sim", "unit", "--seed", "7", "--out", &p(d.path(), "u2.toml")]);
    assert_eq!(std::fs::read(d.path().join("u.toml")).unwrap(), std::fs::read(d.path().join("u2.toml")).unwrap());
    for f in ["a.csv", "b.csv"] {
        ok(&[
            "sim",
            "dataset",
            "--unit",
            &p(d.path(), "u.toml"),
            "--step-deg",
            "6",
            "--seed",
            "3",
            "--out",
            &p(d.path(), f),
        ]);
    }
    let a = std::fs::read(d.path().join("a.csv")).unwrap();
    assert_eq!(a, std::fs::read(d.path().join("b.csv")).unwrap());
    let data = abvs_eye::dataset::Dataset::read(&d.path().join("a.csv")).unwrap();
    // 11 x 6 x 11 commanded poses, ~5% measurement failures.
    assert!(data.len() > 600 && data.len() < 726, "{}", data.len());
    // A different seed gives different noise.
    ok(&[
        "sim",
        "dataset",
        "--unit",
        &p(d.path(), "u.toml"),
        "--step-deg",
        "6",
        "--seed",
        "4",
        "--out",
        &p(d.path(), "c.csv"),
    ]);
    assert_ne!(a, std::fs::read(d.path().join("c.csv")).unwrap());
    // The n^3 fine-tuning layout.
    ok(&[
        "sim",
        "dataset",
        "--unit",
        &p(d.path(), "u.toml"),
        "--grid-n",
        "4",
        "--dropout",
        "0",
        "--out",
        &p(d.path(), "n4.csv"),
    ]);
    assert_eq!(abvs_eye::dataset::Dataset::read(&d.path().join("n4.csv")).unwrap().len(), 64);
}

#[test]
fn kin_ik_then_fk_round_trips_and_keeps_other_columns() {
    let d = tempfile::tempdir().unwrap();
    let poses = "label,alpha_deg,beta_deg,gamma_deg\nA,0,0,0\nB,-11,-7,-26\nC,30,15,30\nD,-30,15,-30\n";
    std::fs::write(d.path().join("poses.csv"), poses).unwrap();
    ok(&["kin", "ik", "--in", &p(d.path(), "poses.csv"), "--out", &p(d.path(), "th.csv")]);
    // FK on the IK output: alpha/beta/gamma columns are replaced by the FK's, x/y/z added.
    ok(&["kin", "fk", "--in", &p(d.path(), "th.csv"), "--out", &p(d.path(), "back.csv")]);
    let mut rd = csv::Reader::from_path(d.path().join("back.csv")).unwrap();
    let h = rd.headers().unwrap().clone();
    assert_eq!(&h[0], "label");
    for col in ["theta1_deg", "x_mm", "z_mm"] {
        assert!(h.iter().any(|c| c == col), "{h:?}");
    }
    let want: Vec<[f64; 3]> = vec![[0.0, 0.0, 0.0], [-11.0, -7.0, -26.0], [30.0, 15.0, 30.0], [-30.0, 15.0, -30.0]];
    for (rec, w) in rd.records().zip(want) {
        let rec = rec.unwrap();
        for (k, name) in ["alpha_deg", "beta_deg", "gamma_deg"].iter().enumerate() {
            let i = h.iter().position(|c| c == *name).unwrap();
            let v: f64 = rec[i].parse().unwrap();
            assert!((v - w[k]).abs() < 1e-9, "{name}: {v} vs {}", w[k]);
        }
        let x: f64 = rec[h.iter().position(|c| c == "x_mm").unwrap()].parse().unwrap();
        assert!(x.abs() < 1e-9, "camera at O1 has no translation");
    }
}

#[test]
fn kin_reports_bad_rows_by_line_and_exits_nonzero() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("poses.csv"), "alpha_deg,beta_deg,gamma_deg\n1,2,3\nabc,0,0\n89,0,0\n-5,4,2\n")
        .unwrap();
    let o = abvs(&["kin", "ik", "--in", &p(d.path(), "poses.csv"), "--out", &p(d.path(), "th.csv")]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("poses.csv:3") && err.contains("alpha_deg") && err.contains("not a number"), "{err}");
    assert!(err.contains("poses.csv:4"), "{err}");
    // Good rows are still written, bad rows kept with empty outputs: nothing is lost.
    let out = std::fs::read_to_string(d.path().join("th.csv")).unwrap();
    assert_eq!(out.lines().count(), 5, "{out}");
    assert!(out.lines().nth(4).unwrap().starts_with("-5,4,2,") && !out.lines().nth(4).unwrap().ends_with(",,"));
    let o = abvs(&["kin", "ik", "--in", &p(d.path(), "missing.csv"), "--out", &p(d.path(), "x.csv")]);
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("missing.csv"));
    std::fs::write(d.path().join("nocol.csv"), "alpha_deg,gamma_deg\n1,2\n").unwrap();
    let o = abvs(&["kin", "ik", "--in", &p(d.path(), "nocol.csv"), "--out", &p(d.path(), "x.csv")]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("nocol.csv:1") && err.contains("beta_deg"), "{err}");
}

#[test]
fn kin_fk_with_a_unit_reproduces_the_simulated_measurements() {
    let d = tempfile::tempdir().unwrap();
    let unit = repo().join("fixtures/units/c1.toml");
    let unit = unit.to_str().unwrap();
    ok(&["sim", "dataset", "--unit", unit, "--step-deg", "10", "--out", &p(d.path(), "m.csv")]);
    ok(&["kin", "fk", "--unit", unit, "--in", &p(d.path(), "m.csv"), "--out", &p(d.path(), "fk.csv")]);
    let m = abvs_eye::dataset::Dataset::read(&d.path().join("m.csv")).unwrap();
    let f = abvs_eye::dataset::Dataset::read(&d.path().join("fk.csv")).unwrap();
    assert_eq!(m.len(), f.len());
    let u = abvs_eye::UnitModel::load(Path::new(unit)).unwrap();
    let sr = u.effects.measurement_noise.rot_deg;
    let st = u.effects.measurement_noise.trans_mm;
    for (a, b) in m.samples.iter().zip(&f.samples) {
        for k in 0..3 {
            assert!((a.pose[k] - b.pose[k]).abs() < 6.0 * sr, "rot {k}: {:?} vs {:?}", a.pose, b.pose);
            assert!((a.pose[3 + k] - b.pose[3 + k]).abs() < 6.0 * st, "trans {k}");
        }
    }
}

#[test]
fn bad_unit_file_is_named_with_its_field() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("u.toml"), "format = \"abvs-unit/1\"\nname = \"x\"\n[effects.hinge_backlash]\nenabled = true\nbacklash_deg = [0.1, \"a\", 0.1]\n").unwrap();
    let o =
        abvs(&["sim", "dataset", "--unit", &p(d.path(), "u.toml"), "--step-deg", "10", "--out", &p(d.path(), "x.csv")]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("u.toml") && err.contains("backlash_deg"), "{err}");
    let o = abvs(&["sim", "unit", "--seed", "1", "--effects", "camera_mount,warp", "--out", &p(d.path(), "v.toml")]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("unknown effect 'warp'"), "{err}");
}

#[test]
fn demo_runs_on_the_embedded_default() {
    let d = tempfile::tempdir().unwrap();
    let out = ok(&["demo", "--out", &p(d.path(), "demo")]);
    assert!(out.contains("nominal kinematics") && out.contains("PSC"), "{out}");
    let s: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.path().join("demo/summary.json")).unwrap()).unwrap();
    let nominal = s["nominal"]["rot_norm_mean_deg"].as_f64().unwrap();
    let floor = s["true_model"]["rot_norm_mean_deg"].as_f64().unwrap();
    // The reason calibration exists: the nominal model is off by far more than the noise floor.
    assert!(nominal > 10.0 * floor, "{nominal} vs {floor}");
    // Calibration closes the gap: the hybrid reaches the floor on held-out poses, hand-eye not.
    let hybrid = s["calibration_test"]["hybrid"]["rot_norm_mean_deg"].as_f64().unwrap();
    let mh = s["calibration_test"]["mh"]["rot_norm_mean_deg"].as_f64().unwrap();
    assert!(hybrid < 1.5 * floor && mh > hybrid, "hybrid {hybrid}, mh {mh}, floor {floor}");
    assert!(d.path().join("demo/model_hybrid/manifest.json").exists());
    for f in ["demo/psc_heatmap.png", "demo/nominal_error_heatmap.png", "demo/dataset_3deg.csv"] {
        assert!(d.path().join(f).metadata().unwrap().len() > 100, "{f}");
    }
    // The embedded default is the committed fixture.
    let fixture = std::fs::read_to_string(repo().join("fixtures/units/c0.toml")).unwrap();
    assert!(fixture.contains("name = \"C0\""));
}

#[test]
fn doctor_finds_onnx_runtime_without_variables() {
    let o = Command::new(env!("CARGO_BIN_EXE_abvs"))
        .arg("doctor")
        .env_remove("ABVS_ORT_DYLIB")
        .env_remove("ORT_DYLIB_PATH")
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success() && out.contains("libonnxruntime.so"), "{out}");
    // The variable overrides the search order, and a wrong one is a clear error.
    let o = Command::new(env!("CARGO_BIN_EXE_abvs"))
        .arg("doctor")
        .env("ABVS_ORT_DYLIB", "/nope/libonnxruntime.so")
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(!o.status.success() && out.contains("/nope/libonnxruntime.so"), "{out}");
}

/// The encoder link end to end: a simulated drive board (a separate `abvs sim board` process)
/// writes frames into one end of a pseudo-terminal pair, the decoder reads the other end; CRC
/// errors, lost frames and a board reset are counted, nothing crashes.
#[test]
fn encoder_stream_through_a_pseudo_terminal() {
    use abvs_board::decoder::{Decoder, LinkEvent};
    use std::io::Read;
    let (mut master, slave) = serialport::TTYPort::pair().expect("pseudo-terminal pair");
    let name = serialport::SerialPort::name(&slave).expect("pty name");
    let mut child = Command::new(env!("CARGO_BIN_EXE_abvs"))
        .args(["sim", "board", "--port", &name, "--frames", "1500", "--rate-hz", "5000"])
        .args(["--corrupt-every", "97", "--drop-every", "101", "--reset-after", "1000"])
        .spawn()
        .unwrap();
    serialport::SerialPort::set_timeout(&mut master, std::time::Duration::from_millis(300)).unwrap();
    let mut d = Decoder::new();
    let mut events = vec![];
    let mut buf = [0u8; 4096];
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(30);
    loop {
        match master.read(&mut buf) {
            Ok(0) => {}
            Ok(n) => events.extend(d.feed(&buf[..n])),
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {
                if child.try_wait().unwrap().is_some() {
                    break;
                }
            }
            Err(e) => panic!("reading the pty: {e}"),
        }
        assert!(std::time::Instant::now() < deadline, "board process did not finish");
    }
    assert!(child.wait().unwrap().success());
    drop(slave);
    let dropped = (0..1500).filter(|k| k % 101 == 100).count() as u64;
    let corrupted = (0..1500).filter(|k| k % 97 == 96 && k % 101 != 100).count() as u64;
    assert_eq!(d.stats.frames, 1500 - dropped - corrupted, "{:?}", d.stats);
    assert!(d.stats.crc_errors >= corrupted, "{:?}", d.stats);
    assert_eq!(d.stats.lost_frames, dropped + corrupted, "{:?}", d.stats);
    assert_eq!(d.stats.resets, 1);
    assert_eq!(events.iter().filter(|e| matches!(e, LinkEvent::Reset(_))).count(), 1);
}

/// The README's default call, `abvs calib explain --data X --out DIR` (no `--model`), on a
/// dataset of the independent simulator (calib/tests/independent) with backlash hidden as a
/// platform lag: it names the effect and writes the report, the plots, the summary and the
/// explained unit. A 30-row dataset still ends in a report; 29 rows end in a clear error.
#[test]
fn calib_explain_default_start_on_independent_data() {
    let d = tempfile::tempdir().unwrap();
    let data = repo().join("calib/tests/independent/data/final/hinge_backlash.csv");
    let out = ok(&["calib", "explain", "--data", data.to_str().unwrap(), "--out", &p(d.path(), "x")]);
    assert!(out.contains("added hinge_backlash"), "{out}");
    assert!(out.contains("start: no starting model given"), "{out}");
    for f in ["report.md", "summary.json", "unit.toml"] {
        assert!(d.path().join("x").join(f).is_file(), "{f} missing");
    }
    let pngs = std::fs::read_dir(d.path().join("x"))
        .unwrap()
        .filter(|e| e.as_ref().unwrap().path().extension().is_some_and(|x| x == "png"));
    assert!(pngs.count() >= 2);
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.path().join("x/summary.json")).unwrap()).unwrap();
    assert!(summary.to_string().contains("hinge_backlash"));
    abvs_eye::UnitModel::load(&d.path().join("x/unit.toml")).expect("the explained unit loads");

    // Degenerate: the first 30 and 29 rows of the same file.
    let text = std::fs::read_to_string(&data).unwrap();
    for (n, good) in [(30, true), (29, false)] {
        let f = d.path().join(format!("rows{n}.csv"));
        std::fs::write(&f, text.lines().take(n + 1).collect::<Vec<_>>().join("\n")).unwrap();
        let o = abvs(&["calib", "explain", "--data", f.to_str().unwrap(), "--out", &p(d.path(), &format!("o{n}"))]);
        assert_eq!(o.status.success(), good, "{n} rows: {}", String::from_utf8_lossy(&o.stderr));
        if !good {
            let e = String::from_utf8_lossy(&o.stderr);
            assert!(e.contains("29 samples") && e.contains("at least 30"), "{e}");
        }
    }
}

/// An offline tool whose reader closes the pipe ends by SIGPIPE like other Unix tools, not with a panic.
#[test]
fn a_closed_stdout_pipe_ends_an_offline_tool_quietly() {
    use std::os::unix::process::ExitStatusExt;
    let mut child = Command::new(env!("CARGO_BIN_EXE_abvs"))
        .arg("doctor")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take()); // the reader goes away before the tool writes
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(o.status.signal(), Some(13), "{:?}: {err}", o.status);
}
