//! The discrepancy workflow on inputs that break naive code: tiny datasets, a link that never
//! moves, every sample at home, duplicated rows, a unit as far from nominal as the paper's,
//! parameters pushed to their bounds, and randomly drawn units up to 3x the effects.md sizes.
//! Each ends in a report or in an error that names the cause: no panic, no abort.
use abvs_calib::explain::{explain, ExplainOptions, ExplainResult};
use abvs_calib::CalibError;
use abvs_eye::dataset::Dataset;
use abvs_eye::sim::{draw_unit, simulate_dataset, Commanded, SimSpec};
use abvs_eye::unit::{Effect, UnitModel};
use proptest::prelude::*;

const GEOMETRIC: [Effect; 5] = [
    Effect::EncoderZeroOffset,
    Effect::LinkAngleError,
    Effect::PlatformAxisError,
    Effect::CameraMount,
    Effect::MeasurementNoise,
];

fn unit(seed: u64, extra: &[Effect]) -> UnitModel {
    let mut on = GEOMETRIC.to_vec();
    on.extend(extra);
    let mut u = draw_unit(seed, &on);
    u.effects.measurement_noise.rot_deg = 0.01;
    u.effects.measurement_noise.trans_mm = 0.05;
    u
}

fn data(u: &UnitModel, commanded: Commanded, seed: u64) -> Dataset {
    let spec = SimSpec { commanded, dropout: 0.0, seed, ..Default::default() };
    simulate_dataset(u, &spec, |_, _| {}).unwrap().0
}

fn run(d: &Dataset) -> Result<ExplainResult, CalibError> {
    explain(&UnitModel::nominal(), d, &ExplainOptions::default(), &mut |_| {})
}

#[test]
fn thirty_samples_end_in_a_report() {
    let u = unit(1, &[]);
    let mut d = data(&u, Commanded::PerAxis(4), 1);
    d.samples.truncate(30);
    let r = run(&d).expect("30 samples are enough to run");
    assert!(r.default_start && r.known_model.contains(&"camera_mount".to_string()));
    assert!(r.final_rms.0.is_finite() && r.noise_floor_rot_deg.is_finite());
    // 29 are refused with the reason.
    d.samples.truncate(29);
    let e = run(&d).unwrap_err().to_string();
    assert!(e.contains("29 samples") && e.contains("at least 30"), "{e}");
}

#[test]
fn forty_samples_with_the_default_start() {
    let u = unit(2, &[]);
    let mut d = data(&u, Commanded::PerAxis(4), 2);
    d.samples.truncate(40);
    let r = run(&d).unwrap();
    assert!(r.steps.is_empty(), "{:?}", r.steps.iter().map(|s| &s.effect).collect::<Vec<_>>());
}

#[test]
fn a_link_that_never_moves() {
    let u = unit(3, &[]);
    let mut d = data(&u, Commanded::PerAxis(5), 3);
    let fk = u.compile().unwrap();
    // Link 2 stuck at its home reading: the poses follow from the other two.
    for s in &mut d.samples {
        s.theta_deg[1] = 0.0;
    }
    let truth = fk.predict_dataset(&d);
    match truth {
        Ok(p) => {
            for (s, p) in d.samples.iter_mut().zip(p) {
                s.pose = p;
            }
            let r = run(&d).expect("a stuck link still gives a report");
            assert!(!r.held.is_empty() || r.start_notes.iter().any(|n| n.contains("held")), "{:?}", r.start_notes);
        }
        Err(e) => panic!("the truth itself must be computable: {e}"),
    }
}

#[test]
fn every_sample_at_home() {
    let u = unit(4, &[]);
    let mut d = data(&u, Commanded::PerAxis(4), 4);
    for s in &mut d.samples {
        s.theta_deg = [0.0; 3];
        s.pose = [0.0; 6];
    }
    let r = run(&d).expect("all at home ends in a report");
    assert!(r.steps.is_empty());
    assert!(r.final_rms.0.is_finite());
}

#[test]
fn duplicated_rows_are_refused_with_file_and_line() {
    let u = unit(5, &[]);
    let d = data(&u, Commanded::PerAxis(4), 5);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("dup.csv");
    d.write(&path).unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    let mut lines: Vec<&str> = text.lines().collect();
    let dup = lines[5];
    lines.insert(6, dup);
    std::fs::write(&path, lines.join("\n")).unwrap();
    let e = Dataset::read(&path).unwrap_err().to_string();
    assert!(e.contains("dup.csv") && e.contains(":7") && e.contains("seq"), "{e}");
}

#[test]
fn a_unit_as_far_from_nominal_as_the_papers() {
    // 7 deg and 12 mm of deviation, mostly camera mount and zero offsets (paper.md).
    let mut u = unit(6, &[]);
    u.effects.camera_mount.rotation_deg = [5.5, -3.0, 4.0];
    u.effects.camera_mount.offset_mm = [2.0, -3.0, 11.5];
    u.effects.encoder_zero_offset.offset_deg = [1.0, -0.8, 0.6];
    let d = data(&u, Commanded::Step(6.0), 6);
    let r = run(&d).unwrap();
    assert!(r.steps.is_empty(), "{:?}", r.steps.iter().map(|s| &s.effect).collect::<Vec<_>>());
    assert!(r.final_rms.0 < 1.3 * r.noise_floor_rot_deg, "{} vs {}", r.final_rms.0, r.noise_floor_rot_deg);
}

#[test]
fn a_parameter_beyond_plausibility_is_reported_with_what_it_absorbs() {
    // A distal arc 4.9 deg off: inside the model's hard limit (5), far beyond a plausible
    // machining error (3x the effects.md range). The fit keeps it and the report flags it.
    let mut u = unit(7, &[]);
    u.effects.link_angle_error.d2_error_deg = [0.2, 4.9, -0.3];
    let d = data(&u, Commanded::Step(6.0), 7);
    let r = run(&d).expect("ends in a report");
    let b = r.at_bounds.iter().find(|b| b.param.contains("d2_error_deg.2")).expect("d2 of leg 2 flagged");
    assert!(b.value > 4.0 && !b.absorbing.is_empty(), "{b:?}");
    let md = abvs_calib::explain::report_markdown(&r, "bound.csv", &[]);
    assert!(md.contains("plausibility bound"), "{md}");
}

#[test]
fn a_fit_driven_past_the_hard_limit_ends_in_a_report() {
    // Deviations from nominal 1.8x those of a unit already at the edge of the limits: no model
    // inside the limits fits; the fit stops at the bounds instead of aborting.
    let mut u = unit(8, &[]);
    u.effects.link_angle_error.d2_error_deg = [0.2, 4.9, -0.3];
    let d0 = data(&u, Commanded::Step(6.0), 8);
    let nominal = UnitModel::nominal().compile().unwrap().predict_dataset(&d0).unwrap();
    let mut d = d0.clone();
    for (s, n) in d.samples.iter_mut().zip(&nominal) {
        for k in 0..3 {
            s.pose[k] = n[k] + 1.8 * (s.pose[k] - n[k]);
        }
    }
    let r = run(&d).expect("a fit at a bound ends in a report");
    assert!(r.final_rms.0.is_finite());
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 6, ..ProptestConfig::default() })]
    /// Random units with every effect up to 3x the effects.md sizes, on small datasets: the
    /// workflow ends in a report or a clear error.
    #[test]
    fn random_units_never_panic(seed in 0u64..10_000, scale in 1.0f64..3.0, n in 4usize..6) {
        let mut u = unit(seed, &[Effect::InputAxisTilt, Effect::CodeWheelEccentricity, Effect::EncoderScale, Effect::HingeBacklash, Effect::GravitySag]);
        for e in Effect::ALL.into_iter().filter(|e| e.is_kinematic()) {
            let p: Vec<f64> = u.params(e).iter().map(|v| v * scale).collect();
            u.set_params(e, &p).unwrap();
        }
        let spec = SimSpec { commanded: Commanded::PerAxis(n), dropout: 0.0, seed, ..Default::default() };
        if let Ok((d, _)) = simulate_dataset(&u, &spec, |_, _| {}) {
            match run(&d) {
                Ok(r) => prop_assert!(r.final_rms.0.is_finite()),
                Err(e) => prop_assert!(!e.to_string().is_empty()),
            }
        }
    }

    /// Degenerate datasets: random subsets, repeated readings, constant poses.
    #[test]
    fn degenerate_datasets_never_panic(seed in 0u64..10_000, keep in 30usize..80, mode in 0u8..3) {
        let u = unit(seed, &[]);
        let mut d = data(&u, Commanded::PerAxis(5), seed);
        d.samples.truncate(keep);
        match mode {
            0 => for s in &mut d.samples { s.theta_deg[2] = s.theta_deg[0]; },
            1 => for s in &mut d.samples { s.pose = [0.1, 0.0, -0.1, 0.0, 0.0, 0.0]; },
            _ => for (i, s) in d.samples.iter_mut().enumerate() { if i % 2 == 1 { s.theta_deg = [0.0; 3]; } },
        }
        match run(&d) {
            Ok(r) => prop_assert!(r.final_rms.0.is_finite()),
            Err(e) => prop_assert!(!e.to_string().is_empty()),
        }
    }
}
