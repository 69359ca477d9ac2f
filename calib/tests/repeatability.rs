//! Repeatability after ISO 9283 (issue 14): the simulator's protocol (30 approaches from random
//! starts to each of five targets, ten images per approach) on units with every effect of
//! effects.md; the tool recovers the session's TRUE repeatability (ISO 9283 on the noise-free
//! poses) within 10% from the measured poses, and says where the measurement limits it.
//! `cargo test -p abvs-calib --test repeatability -- --nocapture` prints the tables.
use abvs_calib::repeatability::{repeatability, table, Figure, TargetRepeatability};
use abvs_eye::dataset::Dataset;
use abvs_eye::sim::{draw_unit, simulate_repeatability, RepeatSpec};
use abvs_eye::unit::Effect;

fn figures(r: &TargetRepeatability) -> [(&'static str, Figure); 5] {
    [
        ("RP_alpha", r.axes[0]),
        ("RP_beta", r.axes[1]),
        ("RP_gamma", r.axes[2]),
        ("RP_rot", r.rotation),
        ("RP_l", r.position),
    ]
}

/// Compares the tool on the measured session with ISO 9283 on the true poses; returns the
/// largest relative error of the figures the tool does not mark as measurement-limited and
/// the names of those it does.
fn compare(name: &str, spec: &RepeatSpec, seed: u64) -> (f64, Vec<String>) {
    let unit = draw_unit(seed, &Effect::ALL);
    let s = simulate_repeatability(&unit, spec).unwrap();
    assert_eq!(s.measured.len(), spec.targets.len() * spec.approaches * spec.images);
    let est = repeatability(&s.measured).unwrap();
    let truth = repeatability(&s.truth).unwrap();
    println!("{name}, unit sim-{seed}: measured\n{}\ntrue (noise-free poses)\n{}", table(&est), table(&truth));
    let (mut worst, mut limited) = (0.0f64, vec![]);
    for (k, (e, t)) in est.iter().zip(&truth).enumerate() {
        assert_eq!((e.approaches, e.images), (spec.approaches, spec.images));
        assert!(t.noise_rot_deg < 1e-6 && t.noise_trans_mm < 1e-6);
        assert!(e.encoder_deg <= 0.01, "{}", e.encoder_deg);
        for ((n, fe), (_, ft)) in figures(e).into_iter().zip(figures(t)) {
            let rel = (fe.value - ft.value).abs() / ft.value;
            if fe.limited() {
                limited.push(format!("P{} {n}", k + 1));
            } else {
                worst = worst.max(rel);
            }
        }
    }
    (worst, limited)
}

#[test]
fn recovers_true_rotational_repeatability_through_camera_noise() {
    // The units' own measurement (AprilGrid-like: 0.005-0.02 deg, 0.02-0.1 mm per image).
    for seed in [1u64, 2, 3] {
        let spec = RepeatSpec { seed, ..Default::default() };
        let (worst, limited) = compare("camera measurement", &spec, seed);
        println!("largest relative error of the resolved figures: {worst:.3}; limited by the measurement: {limited:?}");
        assert!(worst <= 0.10, "sim-{seed}: {worst}");
        // Rotation is resolved everywhere; the optical centre moves by thousandths of a mm,
        // below this measurement's noise: flagged, not reported as if measured.
        assert!(limited.iter().all(|l| l.ends_with("RP_l")), "{limited:?}");
    }
}

#[test]
fn recovers_position_repeatability_with_a_fine_measurement() {
    // A laser-tracker-grade measurement, as ISO 9283 asks: every figure resolved.
    let spec = RepeatSpec { seed: 4, measurement: Some((0.0005, 0.0002)), ..Default::default() };
    let (worst, limited) = compare("fine measurement", &spec, 1);
    assert!(limited.is_empty(), "{limited:?}");
    assert!(worst <= 0.10, "{worst}");
}

#[test]
fn approaches_without_the_approach_column_and_bad_sessions() {
    let unit = draw_unit(5, &Effect::ALL);
    let spec = RepeatSpec { seed: 5, images: 1, ..Default::default() };
    let s = simulate_repeatability(&unit, &spec).unwrap();
    // Without the target/approach columns a new approach starts where the readings change.
    let bare = Dataset {
        samples: s.measured.samples.iter().map(|x| abvs_eye::dataset::Sample { extra: vec![], ..x.clone() }).collect(),
        extra_columns: vec![],
    };
    let (a, b) = (repeatability(&s.measured).unwrap(), repeatability(&bare).unwrap());
    for (x, y) in a.iter().zip(&b) {
        assert!(y.approaches <= 30 && y.approaches >= 26, "{}", y.approaches);
        assert!((x.rotation.value - y.rotation.value).abs() < 0.15 * x.rotation.value);
    }
    // The same session written and read back gives the same table.
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("session.csv");
    s.measured.write(&p).unwrap();
    assert_eq!(repeatability(&Dataset::read(&p).unwrap()).unwrap(), a);
    // No commanded pose; a target approached once.
    let no_cmd = Dataset {
        samples: s.measured.samples.iter().map(|x| abvs_eye::dataset::Sample { cmd_deg: None, ..x.clone() }).collect(),
        extra_columns: s.measured.extra_columns.clone(),
    };
    let e = repeatability(&no_cmd).unwrap_err().to_string();
    assert!(e.contains("cmd_alpha_deg"), "{e}");
    let once = Dataset { samples: s.measured.samples[..1].to_vec(), extra_columns: s.measured.extra_columns.clone() };
    let e = repeatability(&once).unwrap_err().to_string();
    assert!(e.contains("1 approach") && e.contains("at least 2"), "{e}");
    let e = simulate_repeatability(&unit, &RepeatSpec { approaches: 1, ..Default::default() }).unwrap_err().to_string();
    assert!(e.contains("at least 2 approaches"), "{e}");
}
