//! The paper's networks end to end: training (M1, M2, frozen layers, determinism), ONNX export
//! checked against ONNX Runtime, import of our own and of PyTorch-style graphs, bad inputs.
use abvs_calib::mlp::{train, Affine, Dense, Net, TrainConfig, TrainReport, M2_OUTPUT_WEIGHTS};
use abvs_calib::onnx_io::{export_onnx, import_onnx, onnx_to_bytes, INPUT_NAME, NOT_MLP, OUTPUT_NAME};
use abvs_calib::CalibError;
use onnx_protobuf::attribute_proto::AttributeType;
use onnx_protobuf::tensor_proto::DataType;
use onnx_protobuf::tensor_shape_proto::{dimension, Dimension};
use onnx_protobuf::{
    type_proto, AttributeProto, GraphProto, ModelProto, NodeProto, OperatorSetIdProto, TensorProto, TensorShapeProto,
    TypeProto, ValueInfoProto,
};
use protobuf::{EnumOrUnknown, Message, MessageField};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::path::Path;
use std::sync::OnceLock;

/// A smooth stand-in for an eye's FK: degrees and millimetres of realistic magnitudes.
fn truth(t: &[f64; 3]) -> [f64; 6] {
    let [a, b, c] = t.map(f64::to_radians);
    [
        40.0 * a.sin() + 10.0 * (b - c).cos(),
        20.0 * b.sin() * a.cos(),
        30.0 * c.sin() + 5.0 * (a + b).sin(),
        12.0 + 8.0 * a.cos() * b.sin(),
        -5.0 + 6.0 * (c - a).sin(),
        30.0 + 4.0 * (a + b + c).cos(),
    ]
}

fn data(n: usize, seed: u64) -> (Vec<[f64; 3]>, Vec<[f64; 6]>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let x: Vec<[f64; 3]> = (0..n).map(|_| std::array::from_fn(|_| rng.gen_range(-40.0..40.0))).collect();
    let y = x.iter().map(truth).collect();
    (x, y)
}

struct Set {
    x: Vec<[f64; 3]>,
    y: Vec<[f64; 6]>,
    vx: Vec<[f64; 3]>,
    vy: Vec<[f64; 6]>,
}

fn set() -> &'static Set {
    static S: OnceLock<Set> = OnceLock::new();
    S.get_or_init(|| {
        let (x, y) = data(2000, 1);
        let (vx, vy) = data(400, 2);
        Set { x, y, vx, vy }
    })
}

fn norms() -> (Affine, Affine) {
    let s = set();
    (Affine::fit(&s.x, 3), Affine::fit(&s.y, 6))
}

fn fast_cfg(epochs: usize) -> TrainConfig {
    TrainConfig { lr: 3e-3, max_epochs: epochs, patience: epochs, seed: 7, ..TrainConfig::default() }
}

fn run(net: &mut Net, cfg: &TrainConfig) -> TrainReport {
    let s = set();
    let mut calls = 0;
    let rep = train(net, &s.x, &s.y, Some((&s.vx, &s.vy)), cfg, &mut |_, _, _| calls += 1).unwrap();
    assert_eq!(calls, rep.epochs);
    assert_eq!(rep.history.len(), rep.epochs);
    rep
}

/// Validation loss of the untrained net (the normalised targets have unit variance, so ~1).
fn initial_val_loss(net: &Net, w: [f64; 6]) -> f64 {
    let s = set();
    let p = net.eval_batch(&s.vx);
    let sw: f64 = w.iter().sum();
    let mut sum = 0.0;
    for (p, y) in p.iter().zip(&s.vy) {
        for j in 0..6 {
            let d = (p[j] - y[j]) / net.output_norm.std[j];
            sum += w[j] * d * d;
        }
    }
    sum / (sw * s.vy.len() as f64)
}

/// A trained M2 (hidden 32) shared by the export tests.
fn trained_m2() -> &'static Net {
    static N: OnceLock<Net> = OnceLock::new();
    N.get_or_init(|| {
        let (ni, no) = norms();
        let mut net = Net::m2(32, 4, 3, ni, no, 3);
        let cfg = TrainConfig { output_weights: M2_OUTPUT_WEIGHTS, ..fast_cfg(200) };
        let before = initial_val_loss(&net, M2_OUTPUT_WEIGHTS);
        let rep = run(&mut net, &cfg);
        eprintln!(
            "M2: val loss {before:.4} -> {:.6} (epoch {}, {:.2} s)",
            rep.best_val_loss, rep.best_epoch, rep.seconds
        );
        assert!(rep.best_val_loss < before / 50.0, "M2 did not learn: {before} -> {}", rep.best_val_loss);
        assert!(rep.best_epoch > 0 && rep.best_epoch <= rep.epochs);
        assert_eq!(rep.best_val_loss, rep.history[rep.best_epoch - 1].1);
        net
    })
}

#[test]
fn m1_learns_a_smooth_map() {
    let (ni, no) = norms();
    let mut net = Net::m1(32, 7, ni, no, 5);
    assert_eq!((net.n_in(), net.n_out(), net.depth()), (3, 6, 7));
    assert_eq!(net.n_params(), 3 * 32 + 32 + 5 * (32 * 32 + 32) + 32 * 6 + 6);
    let before = initial_val_loss(&net, [1.0; 6]);
    let rep = run(&mut net, &fast_cfg(200));
    eprintln!("M1: val loss {before:.4} -> {:.6} (epoch {}, {:.2} s)", rep.best_val_loss, rep.best_epoch, rep.seconds);
    assert!(rep.best_val_loss < before / 50.0, "M1 did not learn: {before} -> {}", rep.best_val_loss);
    // The kept weights are the best epoch's: recomputing the validation loss gives it back.
    let again = initial_val_loss(&net, [1.0; 6]);
    assert!((again - rep.best_val_loss).abs() < 1e-4 * rep.best_val_loss, "{again} vs {}", rep.best_val_loss);
    // And in raw units the fit is good to a fraction of a degree / millimetre.
    let s = set();
    let worst = net
        .eval_batch(&s.vx)
        .iter()
        .zip(&s.vy)
        .flat_map(|(p, y)| (0..6).map(move |j| (p[j] - y[j]).abs()))
        .fold(0.0, f64::max);
    assert!(worst < 2.0, "worst validation error {worst}");
}

#[test]
fn m2_learns_with_output_weights() {
    let net = trained_m2();
    assert_eq!((net.trunk.len(), net.heads.len(), net.depth()), (4, 2, 7));
    assert!(net.heads.iter().all(|h| h.len() == 3 && h[2].n_out == 3));
    // The weighting favours rotation: its normalised error ends up lower than translation's.
    let s = set();
    let p = net.eval_batch(&s.vx);
    let mse = |cols: std::ops::Range<usize>| {
        let n = (cols.len() * p.len()) as f64;
        let sum: f64 = p
            .iter()
            .zip(&s.vy)
            .flat_map(|(p, y)| cols.clone().map(move |j| ((p[j] - y[j]) / net.output_norm.std[j]).powi(2)))
            .sum();
        sum / n
    };
    eprintln!("M2 normalised MSE: rotation {:.2e}, translation {:.2e}", mse(0..3), mse(3..6));
    assert!(mse(0..3) < 1e-2 && mse(3..6) < 1e-2);
}

fn layers(net: &Net) -> Vec<(usize, &Dense)> {
    net.layers().collect()
}

#[test]
fn frozen_layers_stay_bit_identical() {
    let (ni, no) = norms();
    // M1 like m1f: first 4 of 7 frozen.
    let base = Net::m1(16, 7, ni.clone(), no.clone(), 11);
    let mut net = base.clone();
    run(&mut net, &TrainConfig { frozen_layers: 4, ..fast_cfg(5) });
    for ((d, a), (_, b)) in layers(&base).into_iter().zip(layers(&net)) {
        if d < 4 {
            assert_eq!(a, b, "frozen layer {d} changed");
        } else {
            assert_ne!(a.w, b.w, "trained layer {d} did not change");
        }
    }
    // M2 with a 2-layer trunk and 3 frozen: the trunk and each head's first layer stay.
    let base = Net::m2(16, 2, 3, ni, no, 12);
    let mut net = base.clone();
    let cfg = TrainConfig { frozen_layers: 3, output_weights: M2_OUTPUT_WEIGHTS, ..fast_cfg(5) };
    run(&mut net, &cfg);
    let mut seen = 0;
    for ((d, a), (_, b)) in layers(&base).into_iter().zip(layers(&net)) {
        if d < 3 {
            assert_eq!(a, b, "frozen layer at depth {d} changed");
            seen += 1;
        } else {
            assert_ne!(a.w, b.w, "trained layer at depth {d} did not change");
        }
    }
    assert_eq!(seen, 4);
    // Freezing everything is refused.
    let e = train(
        &mut net.clone(),
        &set().x,
        &set().y,
        None,
        &TrainConfig { frozen_layers: 5, ..fast_cfg(1) },
        &mut |_, _, _| {},
    )
    .unwrap_err();
    assert!(matches!(e, CalibError::Invalid(_)), "{e}");
}

#[test]
fn training_is_deterministic() {
    let (ni, no) = norms();
    let go = |seed: u64| {
        let mut net = Net::m2(16, 2, 2, ni.clone(), no.clone(), 4);
        let rep = run(&mut net, &TrainConfig { seed, ..fast_cfg(8) });
        (net, rep.history)
    };
    let (a, ha) = go(1);
    let (b, hb) = go(1);
    assert_eq!(a, b);
    assert_eq!(ha, hb);
    let (c, _) = go(2);
    assert_ne!(a, c, "the shuffling seed has no effect");
    assert_eq!(Net::m1(8, 3, ni.clone(), no.clone(), 9), Net::m1(8, 3, ni.clone(), no.clone(), 9));
    assert_ne!(Net::m1(8, 3, ni.clone(), no.clone(), 9), Net::m1(8, 3, ni, no, 10));
}

#[test]
fn no_validation_set_keeps_best_training_loss() {
    let (ni, no) = norms();
    let mut net = Net::m1(8, 3, ni, no, 1);
    let s = set();
    let cfg = TrainConfig { patience: 3, ..fast_cfg(10) };
    let rep = train(&mut net, &s.x, &s.y, None, &cfg, &mut |_, _, v| assert!(v.is_nan())).unwrap();
    let best = rep.history.iter().map(|h| h.0).fold(f64::INFINITY, f64::min);
    assert_eq!(rep.best_val_loss, best);
    assert!(rep.history.iter().all(|h| h.1.is_nan()));
}

fn ort_eval(path: &Path, xs: &[[f64; 3]]) -> Vec<[f64; 6]> {
    let mut s = abvs_onnx::session(path, 1).expect("ONNX Runtime session");
    let input = ndarray::Array2::<f32>::from_shape_fn((xs.len(), 3), |(i, j)| xs[i][j] as f32);
    let tensor = ort::value::TensorRef::from_array_view(&input).unwrap();
    let out = s.run(ort::inputs![INPUT_NAME => tensor]).unwrap();
    let (shape, v) = out[OUTPUT_NAME].try_extract_tensor::<f32>().unwrap();
    assert_eq!(&shape[..], &[xs.len() as i64, 6]);
    v.chunks_exact(6).map(|r| std::array::from_fn(|j| r[j] as f64)).collect()
}

fn assert_close(a: &[[f64; 6]], b: &[[f64; 6]], rel: f64) {
    assert_eq!(a.len(), b.len());
    for (i, (p, q)) in a.iter().zip(b).enumerate() {
        for j in 0..6 {
            assert!((p[j] - q[j]).abs() <= rel * (1.0 + q[j].abs()), "sample {i} column {j}: {} vs {}", p[j], q[j]);
        }
    }
}

#[test]
fn export_runs_in_ort_like_native() {
    let dir = tempfile::tempdir().unwrap();
    let (ni, no) = norms();
    let xs = &set().vx[..100];
    for (name, net) in [("m2", trained_m2().clone()), ("m1", Net::m1(32, 7, ni, no, 2))] {
        let path = dir.path().join(format!("{name}.onnx"));
        export_onnx(&net, &path).unwrap();
        assert_close(&ort_eval(&path, xs), &net.eval_batch(xs), 1e-4);
        // Batch 1 too (the per-frame shape).
        assert_close(&ort_eval(&path, &xs[..1]), &[net.eval(&xs[0])], 1e-4);
    }
}

#[test]
fn export_import_round_trip_is_exact() {
    let dir = tempfile::tempdir().unwrap();
    let (ni, no) = norms();
    // Normalisations that are not f32 values: exact thanks to the f64 metadata.
    assert_ne!(ni.std[0] as f32 as f64, ni.std[0]);
    for net in [trained_m2().clone(), Net::m1(16, 7, ni.clone(), no.clone(), 3), Net::m2(8, 0, 2, ni, no, 4)] {
        let path = dir.path().join("net.onnx");
        export_onnx(&net, &path).unwrap();
        let back = import_onnx(&path).unwrap();
        assert_eq!(back, net);
        for x in &set().vx[..20] {
            assert_eq!(back.eval(x), net.eval(x));
        }
        assert_eq!(onnx_to_bytes(&back), std::fs::read(&path).unwrap());
    }
}

// ---------------------------------------------------------------------------------------------
// Hand-built graphs (what torch.onnx.export produces for an nn.Sequential of Linear/ReLU).

fn tensor(name: &str, dims: &[usize], data: &[f32]) -> TensorProto {
    TensorProto {
        name: name.into(),
        dims: dims.iter().map(|d| *d as i64).collect(),
        data_type: DataType::FLOAT as i32,
        float_data: data.to_vec(),
        ..Default::default()
    }
}

fn node(op: &str, inputs: &[&str], output: &str, attrs: &[(&str, i64)]) -> NodeProto {
    NodeProto {
        op_type: op.into(),
        name: format!("/{output}/{op}"),
        input: inputs.iter().map(|s| s.to_string()).collect(),
        output: vec![output.into()],
        attribute: attrs
            .iter()
            .map(|(n, v)| AttributeProto {
                name: n.to_string(),
                type_: EnumOrUnknown::new(AttributeType::INT),
                i: *v,
                ..Default::default()
            })
            .collect(),
        ..Default::default()
    }
}

fn value(name: &str, dims: &[dimension::Value]) -> ValueInfoProto {
    ValueInfoProto {
        name: name.into(),
        type_: MessageField::some(TypeProto {
            value: Some(type_proto::Value::TensorType(type_proto::Tensor {
                elem_type: DataType::FLOAT as i32,
                shape: MessageField::some(TensorShapeProto {
                    dim: dims.iter().map(|v| Dimension { value: Some(v.clone()), ..Default::default() }).collect(),
                    ..Default::default()
                }),
                ..Default::default()
            })),
            ..Default::default()
        }),
        ..Default::default()
    }
}

fn batch(width: i64) -> Vec<dimension::Value> {
    vec![dimension::Value::DimParam("batch_size".into()), dimension::Value::DimValue(width)]
}

fn model(nodes: Vec<NodeProto>, inits: Vec<TensorProto>, n_in: i64) -> Vec<u8> {
    ModelProto {
        ir_version: 8,
        opset_import: vec![OperatorSetIdProto { version: 17, ..Default::default() }],
        producer_name: "pytorch".into(),
        graph: MessageField::some(GraphProto {
            name: "main_graph".into(),
            node: nodes,
            initializer: inits,
            input: vec![value(INPUT_NAME, &batch(n_in))],
            output: vec![value(OUTPUT_NAME, &batch(6))],
            ..Default::default()
        }),
        ..Default::default()
    }
    .write_to_bytes()
    .unwrap()
}

fn f32s(v: &[f64]) -> Vec<f32> {
    v.iter().map(|x| *x as f32).collect()
}

/// `[in, out]` (PyTorch's MatMul weight) from a Dense.
fn transposed(l: &Dense) -> Vec<f32> {
    (0..l.n_in * l.n_out).map(|i| l.w[(i % l.n_out) * l.n_in + i / l.n_out]).collect()
}

/// An M1-shaped net as PyTorch exports it: Flatten, Sub/Div, MatMul + Add + Relu, Identity,
/// Mul/Add. `act` replaces Relu (to make unsupported graphs).
fn torch_m1(net: &Net, act: &str) -> Vec<u8> {
    let mut nodes = vec![
        node("Flatten", &[INPUT_NAME], "flat", &[("axis", 1)]),
        node("Sub", &["flat", "mu"], "centred", &[]),
        node("Div", &["centred", "sigma"], "h0", &[]),
    ];
    let mut inits = vec![
        tensor("mu", &[3], &f32s(&net.input_norm.mean)),
        tensor("sigma", &[1, 3], &f32s(&net.input_norm.std)),
        tensor("out_sigma", &[6], &f32s(&net.output_norm.std)),
        tensor("out_mu", &[1, 6], &f32s(&net.output_norm.mean)),
    ];
    let n = net.trunk.len();
    let n_in = net.trunk[0].n_in as i64;
    for (i, l) in net.trunk.iter().enumerate() {
        let (w, b) = (format!("onnx::MatMul_{i}"), format!("layers.{i}.bias"));
        inits.push(tensor(&w, &[l.n_in, l.n_out], &transposed(l)));
        inits.push(tensor(&b, &[l.n_out], &l.b));
        let h = format!("h{i}");
        nodes.push(node("MatMul", &[&h, &w], &format!("mm{i}"), &[]));
        nodes.push(node("Add", &[&b, &format!("mm{i}")], &format!("z{i}"), &[]));
        if i + 1 < n {
            nodes.push(node(act, &[&format!("z{i}")], &format!("r{i}"), &[]));
            nodes.push(node("Identity", &[&format!("r{i}")], &format!("h{}", i + 1), &[]));
        }
    }
    nodes.push(node("Mul", &[&format!("z{}", n - 1), "out_sigma"], "scaled", &[]));
    nodes.push(node("Add", &["scaled", "out_mu"], OUTPUT_NAME, &[]));
    model(nodes, inits, n_in)
}

/// An M2-shaped net with Gemm(transB=0), a Constant node for the input scaling written as
/// Mul(1/std), and the trunk's Relu applied separately in each branch.
fn torch_m2(net: &Net) -> Vec<u8> {
    let inv: Vec<f32> = net.input_norm.std.iter().map(|s| (1.0 / s) as f32).collect();
    let mut nodes = vec![
        NodeProto {
            op_type: "Constant".into(),
            output: vec!["inv_std".into()],
            attribute: vec![AttributeProto {
                name: "value".into(),
                type_: EnumOrUnknown::new(AttributeType::TENSOR),
                t: MessageField::some(tensor("", &[3], &inv)),
                ..Default::default()
            }],
            ..Default::default()
        },
        node("Sub", &[INPUT_NAME, "mu"], "c", &[]),
        node("Mul", &["c", "inv_std"], "x0", &[]),
    ];
    let mut inits = vec![
        tensor("mu", &[3], &f32s(&net.input_norm.mean)),
        tensor("out_sigma", &[6], &f32s(&net.output_norm.std)),
        tensor("out_mu", &[6], &f32s(&net.output_norm.mean)),
    ];
    let mut gemm = |l: &Dense, name: &str, input: &str, nodes: &mut Vec<NodeProto>| {
        inits.push(tensor(&format!("{name}.w"), &[l.n_in, l.n_out], &transposed(l)));
        inits.push(tensor(&format!("{name}.b"), &[1, l.n_out], &l.b));
        let (w, b) = (format!("{name}.w"), format!("{name}.b"));
        nodes.push(node("Gemm", &[input, &w, &b], name, &[("transB", 0)]));
    };
    let mut cur = "x0".to_string();
    let t = net.trunk.len();
    for (i, l) in net.trunk.iter().enumerate() {
        gemm(l, &format!("t{i}"), &cur, &mut nodes);
        cur = format!("t{i}");
        if i + 1 < t {
            nodes.push(node("Relu", &[&cur], &format!("{cur}r"), &[]));
            cur = format!("{cur}r");
        }
    }
    let mut ends = vec![];
    for (h, head) in net.heads.iter().enumerate() {
        nodes.push(node("Relu", &[&cur], &format!("b{h}in"), &[]));
        let mut c = format!("b{h}in");
        for (i, l) in head.iter().enumerate() {
            gemm(l, &format!("b{h}_{i}"), &c, &mut nodes);
            c = format!("b{h}_{i}");
            if i + 1 < head.len() {
                nodes.push(node("Relu", &[&c], &format!("{c}r"), &[]));
                c = format!("{c}r");
            }
        }
        ends.push(c);
    }
    nodes.push(node("Concat", &[&ends[0], &ends[1]], "y", &[("axis", 1)]));
    nodes.push(node("Mul", &["y", "out_sigma"], "ys", &[]));
    nodes.push(node("Add", &["ys", "out_mu"], OUTPUT_NAME, &[]));
    model(nodes, inits, 3)
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> std::path::PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

#[test]
fn pytorch_style_graphs_import_and_match_ort() {
    let dir = tempfile::tempdir().unwrap();
    let xs = &set().vx[..50];
    let (ni, no) = norms();
    let m1 = Net::m1(24, 7, ni, no, 8);
    let path = write(dir.path(), "torch_m1.onnx", &torch_m1(&m1, "Relu"));
    let net = import_onnx(&path).unwrap();
    // Same layers (the transposition is exact); the normalisation comes back via f32.
    assert_eq!(net.trunk, m1.trunk);
    assert!(net.heads.is_empty());
    assert_close(&net.eval_batch(xs), &ort_eval(&path, xs), 1e-4);
    for x in &xs[..5] {
        assert_close(&[net.eval(x)], &[m1.eval(x)], 1e-5);
    }

    let m2 = trained_m2();
    let path = write(dir.path(), "torch_m2.onnx", &torch_m2(m2));
    let net = import_onnx(&path).unwrap();
    assert_eq!((net.trunk.len(), net.heads.len()), (4, 2));
    assert_eq!(net.heads, m2.heads);
    assert_eq!(net.trunk, m2.trunk);
    assert_close(&net.eval_batch(xs), &ort_eval(&path, xs), 1e-4);
    assert_close(&net.eval_batch(xs), &m2.eval_batch(xs), 1e-4);
}

fn import_err(bytes: &[u8]) -> String {
    let dir = tempfile::tempdir().unwrap();
    let path = write(dir.path(), "bad.onnx", bytes);
    let e = import_onnx(&path).unwrap_err();
    // Not an MLP (typed, so the model loader can hand it to ONNX Runtime) or malformed.
    assert!(matches!(e, CalibError::Model { .. } | CalibError::NotMlp { .. }), "{e:?}");
    let msg = e.to_string();
    assert!(msg.contains("bad.onnx"), "{msg}");
    msg
}

#[test]
fn bad_graphs_are_clear_errors() {
    let (ni, no) = norms();
    let net = Net::m1(8, 3, ni, no.clone(), 1);
    // A 4-input network.
    let wide = Net::m1(8, 3, Affine::fit(&[[1.0, 2.0, 3.0, 4.0]], 4), no, 1);
    let msg = import_err(&torch_m1(&wide, "Relu"));
    assert!(msg.contains("expected float32 shape [N, 3]") && msg.contains("[batch_size, 4]"), "{msg}");
    // Sigmoid: not ours to run natively, but fine for ONNX Runtime (the fallback).
    let bytes = torch_m1(&net, "Sigmoid");
    let msg = import_err(&bytes);
    assert!(msg.contains(NOT_MLP) && msg.contains("Sigmoid"), "{msg}");
    let dir = tempfile::tempdir().unwrap();
    let path = write(dir.path(), "sigmoid.onnx", &bytes);
    assert_eq!(ort_eval(&path, &set().vx[..3]).len(), 3);
    // Two non-constant operands (a residual connection) is not an MLP either.
    let mut m = ModelProto::parse_from_bytes(&torch_m1(&net, "Relu")).unwrap();
    let g = m.graph.as_mut().unwrap();
    let i = g.node.iter().position(|n| n.op_type == "Add").unwrap();
    g.node[i].input[0] = "h0".into();
    let msg = import_err(&m.write_to_bytes().unwrap());
    assert!(msg.contains(NOT_MLP), "{msg}");
    // Garbage.
    let msg = import_err(b"certainly not protobuf \xff\xff\xff");
    assert!(msg.contains("not an ONNX model"), "{msg}");
    // A missing file names the path.
    let e = import_onnx(Path::new("/nonexistent/dir/net.onnx")).unwrap_err().to_string();
    assert!(e.contains("/nonexistent/dir/net.onnx"), "{e}");
}

#[test]
fn bad_training_data_is_a_clear_error() {
    let (ni, no) = norms();
    let mut net = Net::m1(8, 3, ni, no, 1);
    let s = set();
    let cfg = fast_cfg(1);
    let mut go = |x: &[[f64; 3]], y: &[[f64; 6]], cfg: &TrainConfig| {
        let e = train(&mut net, x, y, None, cfg, &mut |_, _, _| {}).unwrap_err();
        assert!(matches!(e, CalibError::Data(_)), "{e:?}");
        e.to_string()
    };
    let mut x = s.x[..50].to_vec();
    x[17][1] = f64::NAN;
    let msg = go(&x, &s.y[..50], &cfg);
    assert!(msg.contains("sample 17") && msg.contains("theta2"), "{msg}");
    let mut y = s.y[..50].to_vec();
    y[33][4] = f64::INFINITY;
    let msg = go(&s.x[..50], &y, &cfg);
    assert!(msg.contains("sample 33") && msg.contains("column 4 (y)"), "{msg}");
    assert!(go(&[], &[], &cfg).contains("empty"));
    assert!(go(&s.x[..5], &s.y[..4], &cfg).contains("5 inputs but 4 targets"));
    assert!(go(&s.x[..5], &s.y[..5], &TrainConfig { batch: 0, ..cfg.clone() }).contains("batch"));
    let mut vx = s.vx[..10].to_vec();
    vx[3][0] = f64::NAN;
    let e = train(&mut net, &s.x, &s.y, Some((&vx, &s.vy[..10])), &cfg, &mut |_, _, _| {}).unwrap_err();
    assert!(e.to_string().contains("validation set sample 3"), "{e}");
}

/// A network with the same contract but ops we do not run natively (here Sigmoid activations,
/// as a PyTorch user might train) drops into a model directory and runs through ONNX Runtime.
#[test]
fn foreign_network_drops_into_a_model_directory() {
    use abvs_calib::model::{FkModel, Manifest, MANIFEST};
    let dir = tempfile::tempdir().unwrap();
    let (ni, no) = norms();
    let net = Net::m1(16, 4, ni, no, 5);
    let path = write(dir.path(), "net.onnx", &torch_m1(&net, "Sigmoid"));
    let mut m = Manifest::new(abvs_calib::methods::Method::M1);
    m.networks.insert("net".into(), "net.onnx".into());
    std::fs::write(dir.path().join(MANIFEST), serde_json::to_string(&m).unwrap()).unwrap();
    let model = FkModel::load(dir.path()).unwrap();
    assert!(model.native_net("net").is_none(), "a Sigmoid graph must not run natively");
    let xs = &set().vx[..20];
    let want = ort_eval(&path, xs);
    let mut st = model.state();
    let got: Vec<[f64; 6]> = xs.iter().map(|x| model.eval(&mut st, x, [0.0, 1.0, 0.0]).unwrap()).collect();
    assert_close(&got, &want, 1e-6);
}
