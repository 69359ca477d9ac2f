//! Kinematics benchmarks: `cargo bench -p abvs-eye --bench kinematics`.
//! Targets on the 2-core VM: warm FK <= 2 us, IK <= 0.5 us; full 1 deg grid well under a minute.
use abvs_eye::psc::psc_at;
use abvs_eye::sim::{draw_unit, simulate_dataset, Commanded, SimSpec};
use abvs_eye::unit::{Conditions, Effect};
use abvs_eye::{Fick, SpmGeometry};
use criterion::{black_box, criterion_group, criterion_main, Criterion};

fn kinematics(c: &mut Criterion) {
    let g = SpmGeometry::nominal();
    let r = Fick::from_deg([12.0, -7.0, -26.0]).to_matrix();
    let th = g.ik(&r).unwrap();
    // The previous frame 1 deg away in every link (a fast pursuit at 25 fps).
    let prev = g.fk_cold(&th.map(|t| t - 1f64.to_radians())).unwrap().r;

    c.bench_function("ik", |b| b.iter(|| g.ik(black_box(&r)).unwrap()));
    c.bench_function("fk_warm_1deg", |b| b.iter(|| g.fk_from(black_box(&th), black_box(&prev)).unwrap()));
    c.bench_function("fk_cold", |b| b.iter(|| g.fk_cold(black_box(&th)).unwrap()));
    c.bench_function("psc", |b| b.iter(|| psc_at(&g, black_box(&th), black_box(&r)).unwrap()));
    c.bench_function("singularity_measure", |b| b.iter(|| g.singularity(black_box(&r), black_box(&th))));

    let unit = draw_unit(0, &Effect::ALL).compile().unwrap();
    let q = th.map(f64::to_degrees);
    let warm = unit.home_platform();
    c.bench_function("unit_fk_all_effects", |b| {
        b.iter(|| unit.pose(black_box(&q), &Conditions::default(), Some(&warm)).unwrap())
    });
}

fn dataset(c: &mut Criterion) {
    let unit = draw_unit(0, &Effect::ALL);
    let mut grp = c.benchmark_group("dataset");
    grp.sample_size(10);
    for step in [3.0, 1.0] {
        let spec = SimSpec { commanded: Commanded::Step(step), ..Default::default() };
        grp.bench_function(format!("simulate_grid_{step}deg"), |b| {
            b.iter(|| simulate_dataset(&unit, &spec, |_, _| {}).unwrap())
        });
    }
    let spec = SimSpec { commanded: Commanded::Step(1.0), ..Default::default() };
    let (data, _) = simulate_dataset(&unit, &spec, |_, _| {}).unwrap();
    let dir = std::env::temp_dir().join("abvs-bench-dataset.csv");
    grp.bench_function("write_csv_1deg", |b| b.iter(|| data.write(&dir).unwrap()));
    grp.bench_function("read_csv_1deg", |b| b.iter(|| abvs_eye::dataset::Dataset::read(&dir).unwrap()));
    grp.finish();
}

criterion_group!(benches, kinematics, dataset);
criterion_main!(benches);
