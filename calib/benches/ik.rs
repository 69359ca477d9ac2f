//! Calibrated IK benchmark: `cargo bench -p abvs-calib --bench ik`.
//! One solve per call (target <= 10 us median for hybrid), targets drawn over the paper's
//! workspace and visited in order, each from the previous solution (motion history advancing).
//! `hybrid`: fitted on 343 samples of a simulated unit with every effect (physics only: on such
//! a unit the residual network does not help and is not kept); `hybrid_residual`: the same with
//! a 4-layer residual network of the fitted width attached (its evaluation cost, small
//! outputs); `m2`: the paper's network (briefly trained: its evaluation cost).
use abvs_calib::ik::CalibratedIk;
use abvs_calib::methods::{fit, FitConfig, Method};
use abvs_calib::mlp::{Affine, Net};
use abvs_calib::model::{save_model, FkModel};
use abvs_eye::sim::{draw_unit, simulate_dataset, Commanded, SimSpec};
use abvs_eye::unit::Effect;
use criterion::{black_box, criterion_group, criterion_main, Criterion};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn quiet() -> impl FnMut(&str, usize, usize, f64, f64) {
    |_, _, _, _, _| {}
}

fn bench_ik(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let unit = draw_unit(11, &Effect::ALL);
    let spec = SimSpec { commanded: Commanded::PerAxis(7), seed: 11, dropout: 0.0, ..Default::default() };
    let (data, _) = simulate_dataset(&unit, &spec, |_, _| {}).unwrap();
    let cfg = FitConfig { lr: 2e-3, max_epochs: 400, patience: 60, ..FitConfig::default() };
    let mut parts = fit(Method::Hybrid, &data, None, &cfg, &mut quiet()).unwrap();
    save_model(&dir.path().join("hybrid"), &parts).unwrap();
    if !parts.nets.iter().any(|(r, _)| r == "residual") {
        let out = Affine { mean: vec![0.0; 6], std: vec![0.005; 6] };
        let net = Net::m1(cfg.residual_hidden, 4, Affine::fit(&[[-30.0; 3], [30.0; 3]], 3), out, 1);
        parts.nets.push(("residual".into(), net));
    }
    save_model(&dir.path().join("hybrid_residual"), &parts).unwrap();
    let (grid, _) = simulate_dataset(
        &unit,
        &SimSpec { commanded: Commanded::Step(5.0), seed: 12, dropout: 0.0, ..Default::default() },
        |_, _| {},
    )
    .unwrap();
    let m2cfg = FitConfig { lr: 2e-3, max_epochs: 100, ..FitConfig::default() };
    save_model(&dir.path().join("m2"), &fit(Method::M2, &grid, None, &m2cfg, &mut quiet()).unwrap()).unwrap();

    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let targets: Vec<[f64; 3]> = (0..1000)
        .map(|_| [rng.gen_range(-30.0..30.0), rng.gen_range(-15.0..15.0), rng.gen_range(-30.0..30.0)])
        .collect();
    for name in ["hybrid", "hybrid_residual", "m2"] {
        let model = FkModel::load(&dir.path().join(name)).unwrap();
        let ik = CalibratedIk::new(&model);
        // A briefly trained network folds here and there: targets it refuses are left out.
        let targets: Vec<[f64; 3]> =
            targets.iter().zip(ik.solve_batch(&targets, &[])).filter(|(_, r)| r.is_ok()).map(|(t, _)| *t).collect();
        eprintln!("{name}: {} targets", targets.len());
        let mut st = model.state();
        let mut k = 0usize;
        c.bench_function(&format!("calibrated_ik_{name}"), |b| {
            b.iter(|| {
                k = (k + 1) % targets.len();
                ik.solve_and_move(&mut st, black_box(targets[k]), [0.0, 1.0, 0.0]).unwrap()
            })
        });
        // On a loaded machine wall time counts the time others had the core: this thread's
        // own CPU time per call (Linux schedstat) is printed next to criterion's figure.
        if let Some(t0) = thread_cpu_ns() {
            let n = 20 * targets.len();
            for i in 0..n {
                black_box(ik.solve_and_move(&mut st, targets[i % targets.len()], [0.0, 1.0, 0.0]).unwrap());
            }
            let per = (thread_cpu_ns().unwrap_or(t0) - t0) as f64 / n as f64 / 1e3;
            eprintln!("calibrated_ik_{name}: {per:.2} us of thread CPU time per call (mean of {n})");
        }
    }
}

/// CPU time this thread has run (ns), from /proc/thread-self/schedstat.
fn thread_cpu_ns() -> Option<u64> {
    std::fs::read_to_string("/proc/thread-self/schedstat").ok()?.split_whitespace().next()?.parse().ok()
}

criterion_group!(benches, bench_ik);
criterion_main!(benches);
