//! Calibration benchmarks: `cargo bench -p abvs-calib --bench fk_model`.
//! FkModel evaluation per call (target <= 2 us incl. the PSC for m4f), m2 training on the
//! paper's 4,851-pose grid (target <= 5 min), m4f fine-tuning on 343 samples.
use abvs_calib::methods::{finetune, fit, FitConfig, Method};
use abvs_calib::model::{save_model, FkModel};
use abvs_eye::dataset::Dataset;
use abvs_eye::sim::{simulate_dataset, Commanded, SimSpec};
use abvs_eye::UnitModel;
use criterion::{black_box, criterion_group, criterion_main, Criterion};
use std::path::Path;

fn unit(name: &str) -> UnitModel {
    UnitModel::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/units").join(name)).unwrap()
}

fn data(u: &UnitModel, commanded: Commanded) -> Dataset {
    simulate_dataset(u, &SimSpec { commanded, ..Default::default() }, |_, _| {}).unwrap().0
}

fn quiet() -> impl FnMut(&str, usize, usize, f64, f64) {
    |_, _, _, _, _| {}
}

fn eval(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let c0 = data(&unit("c0.toml"), Commanded::Step(3.0));
    let c1 = data(&unit("c1.toml"), Commanded::PerAxis(7));
    // Few epochs: the evaluation cost does not depend on how well the nets are trained.
    let cfg = FitConfig { max_epochs: 20, ..FitConfig::default() };
    let mut models = vec![];
    for (name, m) in [("mh", Method::Mh), ("hybrid", Method::Hybrid), ("m1", Method::M1), ("m2", Method::M2)] {
        let parts = fit(m, &c0, None, &cfg, &mut quiet()).unwrap();
        save_model(&dir.path().join(name), &parts).unwrap();
        models.push(name.to_string());
    }
    let base = FkModel::load(&dir.path().join("m2")).unwrap();
    let parts = finetune(Method::M4f, &base, &c1, None, &cfg, &mut quiet()).unwrap();
    save_model(&dir.path().join("m4f"), &parts).unwrap();
    models.push("m4f".into());

    // A pursuit through the workspace: consecutive readings 0.5 deg apart, as at 25 fps.
    let thetas: Vec<[f64; 3]> = c0.samples.iter().map(|s| s.theta_deg).collect();
    for name in models {
        let m = FkModel::load(&dir.path().join(&name)).unwrap();
        let mut st = m.state();
        let mut k = 0usize;
        c.bench_function(&format!("fk_model_eval_{name}"), |b| {
            b.iter(|| {
                k = (k + 1) % thetas.len();
                m.eval(&mut st, black_box(&thetas[k]), [0.0, 1.0, 0.0]).unwrap()
            })
        });
    }
}

fn training(c: &mut Criterion) {
    let c0 = data(&unit("c0.toml"), Commanded::Step(3.0));
    let c1 = data(&unit("c1.toml"), Commanded::PerAxis(7));
    let mut g = c.benchmark_group("training");
    g.sample_size(10);
    let full = FitConfig::default();
    g.bench_function("train_m2_4851_1000_epochs", |b| {
        b.iter(|| fit(Method::M2, &c0, None, &full, &mut quiet()).unwrap())
    });
    let dir = tempfile::tempdir().unwrap();
    save_model(
        dir.path(),
        &fit(Method::M2, &c0, None, &FitConfig { max_epochs: 50, ..full.clone() }, &mut quiet()).unwrap(),
    )
    .unwrap();
    let base = FkModel::load(dir.path()).unwrap();
    g.bench_function("finetune_m4f_343", |b| {
        b.iter(|| finetune(Method::M4f, &base, &c1, None, &full, &mut quiet()).unwrap())
    });
    g.bench_function("fit_hybrid_343", |b| b.iter(|| fit(Method::Hybrid, &c1, None, &full, &mut quiet()).unwrap()));
    g.finish();
}

criterion_group!(benches, eval, training);
criterion_main!(benches);
