//! Every calibration method trains on a small simulated set and beats hand-eye (M_h); models
//! round-trip through their files; bad inputs give clear errors.
use abvs_calib::methods::{finetune, fit, FitConfig, Method};
use abvs_calib::metrics::evaluate;
use abvs_calib::model::{save_model, FkModel};
use abvs_calib::mpe::Target;
use abvs_calib::CalibError;
use abvs_eye::dataset::Dataset;
use abvs_eye::psc::psc_at;
use abvs_eye::sim::{draw_unit, simulate_dataset, Commanded, SimSpec};
use abvs_eye::unit::{Effect, UnitModel};
use abvs_eye::SpmGeometry;
use std::path::Path;

/// A unit with paper-sized geometric errors (the paper's ideal-vs-measured deviation reaches
/// 7 deg): effects.md magnitudes of the link and axis errors scaled up 4x, so that the camera
/// mount alone (M_h) cannot explain the unit.
fn paper_sized(seed: u64) -> UnitModel {
    let mut u = draw_unit(
        seed,
        &[
            Effect::EncoderZeroOffset,
            Effect::LinkAngleError,
            Effect::InputAxisTilt,
            Effect::PlatformAxisError,
            Effect::CameraMount,
            Effect::MeasurementNoise,
        ],
    );
    for e in [Effect::LinkAngleError, Effect::PlatformAxisError, Effect::InputAxisTilt] {
        let p: Vec<f64> = u.params(e).iter().map(|v| 4.0 * v).collect();
        u.set_params(e, &p).unwrap();
    }
    u
}

fn sim(u: &UnitModel, commanded: Commanded, seed: u64) -> Dataset {
    simulate_dataset(u, &SimSpec { commanded, seed, dropout: 0.0, ..Default::default() }, |_, _| {}).unwrap().0
}

fn quiet() -> impl FnMut(&str, usize, usize, f64, f64) {
    |_, _, _, _, _| {}
}

fn rot_error(dir: &Path, test: &Dataset) -> f64 {
    let m = FkModel::load(dir).unwrap();
    let pred = m.predict_dataset(test).unwrap();
    let meas: Vec<[f64; 6]> = test.samples.iter().map(|s| s.pose).collect();
    evaluate(&pred, &meas, &Target::paper()).rot_norm_mean_deg
}

#[test]
fn every_method_beats_hand_eye_on_a_small_set() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (paper_sized(101), paper_sized(102));
    let train_a = sim(&a, Commanded::Step(5.0), 1);
    let train_b = sim(&b, Commanded::PerAxis(7), 2);
    let test_b = sim(&b, Commanded::Step(7.0), 3);
    let test_a = sim(&a, Commanded::Step(7.0), 4);
    // A faster schedule than the paper's (lr 1e-4, 1000 epochs) keeps the test short.
    let cfg = FitConfig { lr: 2e-3, max_epochs: 400, patience: 60, ..FitConfig::default() };
    let save = |name: &str, parts| {
        save_model(&dir.path().join(name), &parts).unwrap();
        dir.path().join(name)
    };
    // The fits are independent (each deterministic from its seed): run on every core, one thread each.
    let on_cores = |jobs: Vec<Box<dyn FnOnce() -> f64 + Send + '_>>| -> Vec<f64> {
        std::thread::scope(|s| {
            let hs: Vec<_> = jobs.into_iter().map(|j| s.spawn(j)).collect();
            hs.into_iter().map(|h| h.join().unwrap()).collect()
        })
    };
    let (train_a, test_a, save, cfg) = (&train_a, &test_a, &save, &cfg);
    let fit_a = |name: &'static str, m: Method| -> Box<dyn FnOnce() -> f64 + Send + '_> {
        Box::new(move || rot_error(&save(name, fit(m, train_a, None, cfg, &mut quiet()).unwrap()), test_a))
    };
    let methods = [Method::M1, Method::M2, Method::Hybrid];
    let mut jobs = vec![fit_a("mh_a", Method::Mh)];
    jobs.extend(methods.map(|m| fit_a(m.name(), m)));
    let e = on_cores(jobs);
    let mh_a = e[0];
    for (m, e) in methods.iter().zip(&e[1..]) {
        assert!(*e < mh_a, "{} {e} vs mh {mh_a}", m.name());
    }
    // Fine-tuning unit B from unit A's models, against M_h fitted on B's own 343 samples.
    let (train_b, test_b) = (&train_b, &test_b);
    let tunes = [(Method::M1f, "m1"), (Method::M2f, "m2"), (Method::M4f, "m2"), (Method::Hybrid, "hybrid")];
    let mut jobs: Vec<Box<dyn FnOnce() -> f64 + Send + '_>> =
        vec![Box::new(|| rot_error(&save("mh_b", fit(Method::Mh, train_b, None, cfg, &mut quiet()).unwrap()), test_b))];
    for (m, base) in tunes {
        let base = FkModel::load(&dir.path().join(base)).unwrap();
        jobs.push(Box::new(move || {
            let parts = finetune(m, &base, train_b, None, cfg, &mut quiet()).unwrap();
            rot_error(&save(&format!("{}_b", m.name()), parts), test_b)
        }));
    }
    let e = on_cores(jobs);
    let mh_b = e[0];
    for ((m, _), e) in tunes.iter().zip(&e[1..]) {
        assert!(*e < mh_b, "{} {e} vs mh {mh_b}", m.name());
    }
    // m4f picks its branch by the exact PSC even where the fast first-order S is used.
    let m4 = FkModel::load(&dir.path().join("m4f_b")).unwrap();
    let split = m4.manifest.psc.unwrap();
    let (inner, outer) = (m4.native_net("internal").unwrap(), m4.native_net("external").unwrap());
    let g = SpmGeometry::nominal();
    let mut st = m4.state();
    for s in &test_b.samples {
        let th = s.theta_deg.map(f64::to_radians);
        let exact = psc_at(&g, &th, &g.fk_cold(&th).unwrap().r).unwrap();
        let want = if exact <= split.s_init { inner.eval(&s.theta_deg) } else { outer.eval(&s.theta_deg) };
        assert_eq!(m4.eval(&mut st, &s.theta_deg, [0.0, 1.0, 0.0]).unwrap(), want);
    }
}

#[test]
fn bad_inputs_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let u = paper_sized(7);
    let cfg = FitConfig { max_epochs: 5, ..FitConfig::default() };
    // Too few samples.
    let tiny = sim(&u, Commanded::PerAxis(2), 1);
    let e = fit(Method::M2, &tiny, None, &cfg, &mut quiet()).err().unwrap().to_string();
    assert!(e.contains("8 samples") && e.contains("at least 16"), "{e}");
    // Model/method mismatch when fine-tuning.
    let data = sim(&u, Commanded::PerAxis(4), 2);
    save_model(&dir.path().join("m1"), &fit(Method::M1, &data, None, &cfg, &mut quiet()).unwrap()).unwrap();
    save_model(&dir.path().join("mh"), &fit(Method::Mh, &data, None, &cfg, &mut quiet()).unwrap()).unwrap();
    let m1 = FkModel::load(&dir.path().join("m1")).unwrap();
    let mh = FkModel::load(&dir.path().join("mh")).unwrap();
    for (m, base) in [(Method::M2f, &m1), (Method::M4f, &m1), (Method::Hybrid, &m1), (Method::M1f, &mh)] {
        match finetune(m, base, &data, None, &cfg, &mut quiet()) {
            Err(CalibError::Mismatch(msg)) => assert!(msg.contains(base.method().name()), "{msg}"),
            other => panic!("{} on {}: expected a mismatch, got {:?}", m.name(), base.method(), other.map(|_| ())),
        }
    }
    // Missing directory, missing network file, foreign manifest.
    let e = FkModel::load(&dir.path().join("nope")).err().unwrap().to_string();
    assert!(e.contains("nope") && e.contains("manifest.json"), "{e}");
    std::fs::remove_file(dir.path().join("m1/net.onnx")).unwrap();
    let e = FkModel::load(&dir.path().join("m1")).err().unwrap().to_string();
    assert!(e.contains("net.onnx") && e.contains("missing"), "{e}");
    std::fs::write(dir.path().join("mh/manifest.json"), "{\"format\": \"something-else\"}").unwrap();
    let e = FkModel::load(&dir.path().join("mh")).err().unwrap().to_string();
    assert!(e.contains("mh/manifest.json"), "{e}");
    // A network whose inputs are not [N, 3].
    let mut wrong = fit(Method::M1, &data, None, &cfg, &mut quiet()).unwrap();
    let net = &mut wrong.nets[0].1;
    net.trunk[0].n_in = 4;
    net.trunk[0].w = vec![0.0; net.trunk[0].n_out * 4];
    net.input_norm.mean.push(0.0);
    net.input_norm.std.push(1.0);
    let r = save_model(&dir.path().join("wrong"), &wrong)
        .and_then(|_| FkModel::load(&dir.path().join("wrong")).map(|_| ()));
    let e = r.expect_err("a 4-input network must be refused").to_string();
    assert!(e.contains('3') && e.contains('4'), "{e}");
}
