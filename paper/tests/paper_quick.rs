//! `abvs calib paper --quick` end to end: every stage runs, the report, the summary and the
//! figures are written, the numbers are finite, and the physics-based hybrid beats hand-eye
//! calibration (M_h) on C0 (it identifies everything M_h fits, and more).
use abvs_paper::{run_paper, PaperConfig};
use serde_json::Value;

fn finite(v: &Value, what: &str) -> f64 {
    let x = v.as_f64().unwrap_or_else(|| panic!("{what}: not a number: {v}"));
    assert!(x.is_finite(), "{what}: {x}");
    x
}

#[test]
fn quick_report_is_complete() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = PaperConfig::quick(7);
    let mut lines = vec![];
    let s = run_paper(&cfg, dir.path(), &mut |l| lines.push(l.to_string())).unwrap();
    assert!(lines.iter().any(|l| l.contains("Table II")), "{lines:?}");

    let report = std::fs::read_to_string(dir.path().join("report.md")).unwrap();
    for heading in ["## Table II", "## Table III", "## Fig. 7", "## Extrapolation", "## Fig. 8", "## Conclusions"] {
        assert!(report.contains(heading), "report.md lacks {heading}");
    }
    let json: Value = serde_json::from_str(&std::fs::read_to_string(dir.path().join("summary.json")).unwrap()).unwrap();

    let row = |table: &str, label: &str| -> Value {
        json[table]
            .as_array()
            .unwrap()
            .iter()
            .find(|r| r["label"] == label && r["unit"] == "C0")
            .unwrap_or_else(|| panic!("{table} has no C0 row {label}"))
            .clone()
    };
    let mse = |r: &Value, what: &str| finite(&r["eval"]["mse_total"], what);
    let mut c0 = std::collections::BTreeMap::new();
    for label in ["M_h", "M1", "M2", "hybrid"] {
        let r = row("table2", label);
        c0.insert(label, mse(&r, label));
        finite(&r["eval"]["mpe_px"], label);
        finite(&r["rot_norm_of_means_deg"], label);
        finite(&r["eval"]["rot_deg"]["alpha"]["max"], label);
    }
    assert!(c0["hybrid"] < c0["M_h"], "hybrid does not beat M_h on C0: {c0:?}");

    let t3 = json["table3"].as_array().unwrap();
    let n = cfg.finetune_units.len();
    assert_eq!(t3.len(), 7 * n, "Table III: 7 rows per fine-tuned unit");
    t3.iter().for_each(|r| {
        mse(r, "table3");
    });
    let fig7 = json["fig7"].as_array().unwrap();
    assert_eq!(fig7.len(), 3 * cfg.finetune_n.len() * n);
    for p in fig7 {
        finite(&p["mse_internal"], "fig7 internal");
        finite(&p["mse_external"], "fig7 external");
    }
    for e in json["extrapolation"].as_array().unwrap() {
        finite(&e["mse_inside"], "extrapolation inside");
        finite(&e["mse_outside"], "extrapolation outside");
    }
    assert!(json["conclusions"].as_array().unwrap().len() >= 6);
    for (k, v) in json["headline"].as_object().unwrap() {
        finite(v, k);
    }

    // Figures exist and the directory holds nothing else (models are removed).
    assert!(s.files.iter().any(|f| f.starts_with("fig7_")) && s.files.iter().any(|f| f.starts_with("fig8_")));
    for f in &s.files {
        let len = std::fs::metadata(dir.path().join(f)).unwrap_or_else(|e| panic!("{f}: {e}")).len();
        assert!(len > 1000, "{f}: {len} bytes");
    }
    let mut listed: Vec<String> =
        std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    listed.sort();
    let mut want = s.files.clone();
    want.sort();
    assert_eq!(listed, want);
}
