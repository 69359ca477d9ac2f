//! Network benchmarks: `cargo bench -p abvs-calib --bench calib`.
//! Targets on the 2-core VM: native batch-1 eval (hidden 64, 7 layers) < 1.5 us; one training
//! epoch of M2 (hidden 64) on 4851 samples well under 0.1 s. `ort_eval_m2_h64` is the baseline
//! the native path replaces (same net through ONNX Runtime, batch 1, one intra-op thread).
use abvs_calib::mlp::{train, Affine, Net, TrainConfig, M2_OUTPUT_WEIGHTS};
use abvs_calib::onnx_io::{export_onnx, INPUT_NAME};
use criterion::{black_box, criterion_group, criterion_main, Criterion};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn norms() -> (Affine, Affine) {
    let input = Affine { mean: vec![0.0; 3], std: vec![20.0; 3] };
    let output = Affine { mean: vec![0.0, 0.0, 0.0, 10.0, 0.0, 30.0], std: vec![15.0, 10.0, 15.0, 5.0, 5.0, 3.0] };
    (input, output)
}

fn samples(n: usize) -> (Vec<[f64; 3]>, Vec<[f64; 6]>) {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let x: Vec<[f64; 3]> = (0..n).map(|_| std::array::from_fn(|_| rng.gen_range(-40.0..40.0))).collect();
    let y = (0..n).map(|_| std::array::from_fn(|_| rng.gen_range(-30.0..30.0))).collect();
    (x, y)
}

fn eval(c: &mut Criterion) {
    let (ni, no) = norms();
    let m1 = Net::m1(64, 7, ni.clone(), no.clone(), 1);
    let m2 = Net::m2(64, 4, 3, ni, no, 2);
    let x = [12.5, -7.25, 30.0];
    c.bench_function("net_eval_m1_h64", |b| b.iter(|| m1.eval(black_box(&x))));
    c.bench_function("net_eval_m2_h64", |b| b.iter(|| m2.eval(black_box(&x))));

    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m2.onnx");
    export_onnx(&m2, &path).unwrap();
    let mut session = abvs_onnx::session(&path, 1).expect("ONNX Runtime");
    // Per frame as a caller would do it: wrap the input, run, read the output.
    c.bench_function("ort_eval_m2_h64", |b| {
        b.iter(|| {
            let input = ndarray::Array2::<f32>::from_shape_fn((1, 3), |(_, j)| x[j] as f32);
            let t = ort::value::TensorRef::from_array_view(&input).unwrap();
            let out = session.run(ort::inputs![INPUT_NAME => t]).unwrap();
            let (_, v) = out[0].try_extract_tensor::<f32>().unwrap();
            let r: [f64; 6] = std::array::from_fn(|k| v[k] as f64);
            r
        })
    });
}

fn training(c: &mut Criterion) {
    let (ni, no) = norms();
    let (x, y) = samples(4851);
    let net = Net::m2(64, 4, 3, ni, no, 3);
    let cfg = TrainConfig { max_epochs: 1, output_weights: M2_OUTPUT_WEIGHTS, ..TrainConfig::default() };
    c.bench_function("train_epoch_m2_h64_4851", |b| {
        b.iter_batched(
            || net.clone(),
            |mut n| train(&mut n, &x, &y, None, &cfg, &mut |_, _, _| {}).unwrap(),
            criterion::BatchSize::LargeInput,
        )
    });
}

criterion_group!(fast, eval);
criterion_group! {
    name = slow;
    config = Criterion::default().sample_size(10);
    targets = training
}
criterion_main!(fast, slow);
