//! `abvs calib ik`, `abvs gaze fixate`, `abvs sim repeatability` and `abvs calib repeatability`
//! end to end on the embedded session's calibration (hybrid models of two simulated eyes).
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

fn calib() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/session/calib")
}

fn s(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

fn read_csv(p: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let mut r = csv::Reader::from_path(p).unwrap();
    let h = r.headers().unwrap().iter().map(String::from).collect();
    (h, r.records().map(|x| x.unwrap().iter().map(String::from).collect()).collect())
}

#[test]
fn calib_ik_reaches_targets_and_round_trips_through_fk() {
    let d = tempfile::tempdir().unwrap();
    let model = calib().join("eye0");
    let targets = d.path().join("t.csv");
    std::fs::write(&targets, "name,alpha_deg,beta_deg,gamma_deg\na,10,5,-20\nb,-25,-10,28\nc,85,0,0\nd,0,0,0\n")
        .unwrap();
    let out = d.path().join("o.csv");
    let o = abvs(&["calib", "ik", "--model", &s(&model), "--in", &s(&targets), "--out", &s(&out)]);
    // The unreachable row is refused by its line; the others are written.
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("t.csv:4") && err.contains("refused"), "{err}");
    let (h, rows) = read_csv(&out);
    let col = |n: &str| h.iter().position(|x| x == n).unwrap_or_else(|| panic!("no column {n}"));
    assert_eq!(h[0], "name");
    assert!(rows[2][col("theta1_deg")].is_empty());
    let good: Vec<&Vec<String>> = rows.iter().filter(|r| !r[col("theta1_deg")].is_empty()).collect();
    assert_eq!(good.len(), 3);
    for r in &good {
        let v = |n: &str| r[col(n)].parse::<f64>().unwrap();
        for a in ["alpha_deg", "beta_deg", "gamma_deg"] {
            assert!((v(&format!("pred_{a}")) - v(a)).abs() < 1e-4, "{r:?}");
        }
        assert!(v("residual_deg") < 1e-4);
        for i in 1..=3 {
            assert_eq!(v(&format!("count{i}")), (v(&format!("theta{i}_deg")) * 92672.0 / 360.0).round());
        }
    }
    // The model is physics only (unit.toml): kin fk of the solved link angles, walked in the
    // same order, gives back the targets.
    let th = d.path().join("th.csv");
    let mut text = String::from("theta1_deg,theta2_deg,theta3_deg\n");
    for r in &good {
        text += &format!("{},{},{}\n", r[col("theta1_deg")], r[col("theta2_deg")], r[col("theta3_deg")]);
    }
    std::fs::write(&th, text).unwrap();
    let back = d.path().join("back.csv");
    ok(&["kin", "fk", "--in", &s(&th), "--out", &s(&back), "--unit", &s(&model.join("unit.toml"))]);
    let (hb, rb) = read_csv(&back);
    for (r, g) in rb.iter().zip(&good) {
        for a in ["alpha_deg", "beta_deg", "gamma_deg"] {
            let x: f64 = r[hb.iter().position(|x| x == a).unwrap()].parse().unwrap();
            assert!((x - g[col(a)].parse::<f64>().unwrap()).abs() < 1e-4, "{a}: {r:?} vs {g:?}");
        }
    }
}

#[test]
fn gaze_fixate_puts_the_point_on_both_principal_points() {
    let out = ok(&["gaze", "fixate", "--calib", &s(&calib()), "--point", "0.05,-0.03,0.5", "--json"]);
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    for eye in ["left", "right"] {
        let e = &v[eye];
        for k in 0..2 {
            let (px, pp) = (e["pixel"][k].as_f64().unwrap(), e["principal_point"][k].as_f64().unwrap());
            assert!((px - pp).abs() < 1e-3, "{eye}: {e}");
        }
        let th = e["theta_deg"].as_array().unwrap();
        for (k, c) in e["counts"].as_array().unwrap().iter().enumerate() {
            assert_eq!(c.as_i64().unwrap(), (th[k].as_f64().unwrap() * 92672.0 / 360.0).round() as i64);
        }
    }
    // About the angle the 65 mm baseline subtends at 0.5 m.
    let verg = v["vergence_deg"].as_f64().unwrap();
    assert!((verg - 7.4).abs() < 0.5, "{verg}");
    let table = ok(&["gaze", "fixate", "--calib", &s(&calib()), "--point", "0,0,1", "--torsion", "zero-fick"]);
    assert!(table.contains("vergence") && table.contains("left (eye0)") && table.contains("zero-fick"), "{table}");
    let o = abvs(&["gaze", "fixate", "--calib", &s(&calib()), "--point", "0,0,-1"]);
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("behind"));
}

#[test]
fn repeatability_session_and_table() {
    let d = tempfile::tempdir().unwrap();
    let unit = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/units/c0.toml");
    let (m, t) = (d.path().join("rep.csv"), d.path().join("truth.csv"));
    let args = ["--approaches", "8", "--images", "3", "--seed", "2"];
    ok(&[&["sim", "repeatability", "--unit", &s(&unit), "--out", &s(&m), "--truth", &s(&t)][..], &args].concat());
    let table = ok(&["calib", "repeatability", "--data", &s(&m)]);
    assert!(table.contains("| P5 |") && table.contains("| worst |") && table.contains("8 x 3"), "{table}");
    let v: serde_json::Value =
        serde_json::from_str(&ok(&["calib", "repeatability", "--data", &s(&t), "--json"])).unwrap();
    let rows = v.as_array().unwrap();
    assert_eq!(rows.len(), 5);
    assert!(rows.iter().all(|r| r["rotation"]["value"].as_f64().unwrap() > 0.0 && r["approaches"] == 8));
}
