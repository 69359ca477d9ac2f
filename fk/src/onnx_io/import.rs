//! Reading plain-MLP ONNX graphs (ours or trained elsewhere) as [`Net`]s (module doc of `onnx_io`).
use super::{META, NOT_MLP, N_IN, N_OUT};
use crate::net::{Affine, Dense, Net};
use crate::{FkError as CalibError, Result};
use onnx_protobuf::attribute_proto::AttributeType;
use onnx_protobuf::tensor_proto::{DataLocation, DataType};
use onnx_protobuf::tensor_shape_proto::dimension;
use onnx_protobuf::{type_proto, AttributeProto, ModelProto, NodeProto, TensorProto, ValueInfoProto};
use protobuf::{Enum, Message};
use std::collections::{HashMap, HashSet};
use std::path::Path;

// ---------------------------------------------------------------------------------------------
// Import

pub fn import_onnx(path: &Path) -> Result<Net> {
    let bytes = std::fs::read(path).map_err(|e| CalibError::io(path, e))?;
    import_onnx_bytes(&bytes, path)
}

/// [`import_onnx`] from memory; `origin` names the source in errors.
pub fn import_onnx_bytes(bytes: &[u8], origin: &Path) -> Result<Net> {
    let model = ModelProto::parse_from_bytes(bytes)
        .map_err(|e| CalibError::model(origin, format!("not an ONNX model: {e}")))?;
    from_model(&model).map_err(|msg| match msg.strip_prefix(NOT_MLP) {
        Some(reason) => {
            CalibError::NotMlp { path: origin.to_path_buf(), reason: reason.trim_start_matches(": ").into() }
        }
        None => CalibError::model(origin, msg),
    })
}

fn not_mlp(reason: impl std::fmt::Display) -> String {
    format!("{NOT_MLP}: {reason}")
}

/// An elementwise op with a per-column constant (already broadcast to the value's width).
#[derive(Debug, Clone)]
enum Ew {
    Add(Vec<f64>),
    Sub(Vec<f64>),
    Mul(Vec<f64>),
    Div(Vec<f64>),
}

/// A non-constant value of the graph, as an op on other such values.
#[derive(Debug, Clone)]
enum Op {
    Input,
    /// Elementwise ops applied in order (consecutive ones are merged into one node).
    Affine {
        src: usize,
        ops: Vec<Ew>,
    },
    /// `y = W x + b`, W `n_out x n_in` row-major.
    Linear {
        src: usize,
        w: Vec<f64>,
        b: Vec<f64>,
    },
    Relu {
        src: usize,
    },
    Concat {
        srcs: Vec<usize>,
    },
}

struct DNode {
    op: Op,
    width: usize,
}

#[derive(Debug, Clone)]
struct Const {
    dims: Vec<i64>,
    data: Vec<f32>,
}

#[derive(Clone)]
enum Val<'a> {
    Init(&'a TensorProto),
    Const(Const),
    Dyn(usize),
}

fn read_tensor(t: &TensorProto) -> std::result::Result<Const, String> {
    let name = &t.name;
    if t.data_location.enum_value() == Ok(DataLocation::EXTERNAL) || !t.external_data.is_empty() {
        return Err(not_mlp(format!("tensor '{name}' uses external data")));
    }
    if t.data_type != DataType::FLOAT as i32 {
        let ty = DataType::from_i32(t.data_type).map_or(format!("#{}", t.data_type), |d| format!("{d:?}"));
        return Err(not_mlp(format!("constant '{name}' is {ty}, not float32")));
    }
    let numel: i64 = t.dims.iter().product();
    let data: Vec<f32> = if !t.raw_data.is_empty() {
        t.raw_data.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect()
    } else {
        t.float_data.clone()
    };
    if t.dims.iter().any(|d| *d < 0) || data.len() as i64 != numel {
        return Err(not_mlp(format!("tensor '{name}' has {} values for shape {:?}", data.len(), t.dims)));
    }
    Ok(Const { dims: t.dims.clone(), data })
}

fn attr<'a>(n: &'a NodeProto, name: &str) -> Option<&'a AttributeProto> {
    n.attribute.iter().find(|a| a.name == name)
}

fn attr_i(n: &NodeProto, name: &str, default: i64) -> std::result::Result<i64, String> {
    match attr(n, name) {
        None => Ok(default),
        Some(a) if a.type_.enum_value() == Ok(AttributeType::INT) => Ok(a.i),
        Some(_) => Err(not_mlp(format!("{} attribute {name} is not an int", n.op_type))),
    }
}

fn attr_f(n: &NodeProto, name: &str, default: f32) -> std::result::Result<f32, String> {
    match attr(n, name) {
        None => Ok(default),
        Some(a) if a.type_.enum_value() == Ok(AttributeType::FLOAT) => Ok(a.f),
        Some(_) => Err(not_mlp(format!("{} attribute {name} is not a float", n.op_type))),
    }
}

/// "[N, 3]" from a declared value type; "unknown" without shape information.
fn shape_str(v: &ValueInfoProto) -> (String, Option<Vec<Option<i64>>>) {
    let Some(type_proto::Value::TensorType(t)) = v.type_.as_ref().and_then(|t| t.value.as_ref()) else {
        return ("a non-tensor".into(), None);
    };
    let ty = if t.elem_type == DataType::FLOAT as i32 {
        String::new()
    } else {
        let d = DataType::from_i32(t.elem_type).map_or(format!("#{}", t.elem_type), |d| format!("{d:?}"));
        format!("{d} ")
    };
    let Some(shape) = t.shape.as_ref() else {
        return (format!("{ty}unknown shape"), None);
    };
    let dims: Vec<Option<i64>> = shape
        .dim
        .iter()
        .map(|d| match &d.value {
            Some(dimension::Value::DimValue(v)) => Some(*v),
            _ => None,
        })
        .collect();
    let txt: Vec<String> = shape
        .dim
        .iter()
        .map(|d| match &d.value {
            Some(dimension::Value::DimValue(v)) => v.to_string(),
            Some(dimension::Value::DimParam(p)) if !p.is_empty() => p.clone(),
            _ => "?".into(),
        })
        .collect();
    (format!("{ty}[{}]", txt.join(", ")), Some(dims))
}

/// Checks a declared graph input/output against float32 `[N, width]` (missing shape
/// information is accepted; the weights are checked later).
fn check_io(what: &str, v: &ValueInfoProto, width: usize) -> std::result::Result<(), String> {
    let (txt, dims) = shape_str(v);
    let float = matches!(
        v.type_.as_ref().and_then(|t| t.value.as_ref()),
        Some(type_proto::Value::TensorType(t)) if t.elem_type == DataType::FLOAT as i32
    );
    let ok = float
        && match &dims {
            None => !txt.starts_with("a non-tensor"),
            Some(d) => d.len() == 2 && d[1].is_none_or(|w| w == width as i64),
        };
    if ok {
        Ok(())
    } else {
        Err(format!("{what} '{}': expected float32 shape [N, {width}], found {txt}", v.name))
    }
}

/// Broadcasts a constant to `width` columns (scalar, `[width]`, `[1, width]`).
fn per_column(c: &Const, width: usize, op: &str) -> std::result::Result<Vec<f64>, String> {
    let dims: Vec<i64> = c.dims.iter().copied().skip_while(|d| *d == 1).collect();
    let v: Vec<f64> = c.data.iter().map(|x| *x as f64).collect();
    if v.len() == 1 {
        Ok(vec![v[0]; width])
    } else if dims.len() == 1 && v.len() == width {
        Ok(v)
    } else {
        Err(not_mlp(format!("{op} with a constant of shape {:?} on {width} columns", c.dims)))
    }
}

fn from_model(model: &ModelProto) -> std::result::Result<Net, String> {
    let g = model.graph.as_ref().ok_or_else(|| "the model has no graph".to_string())?;
    let init_names: HashSet<&str> = g.initializer.iter().map(|t| t.name.as_str()).collect();
    let inputs: Vec<&ValueInfoProto> = g.input.iter().filter(|i| !init_names.contains(i.name.as_str())).collect();
    if inputs.len() != 1 || g.output.len() != 1 {
        let names = |v: &mut dyn Iterator<Item = &ValueInfoProto>| {
            v.map(|i| format!("'{}'", i.name)).collect::<Vec<_>>().join(", ")
        };
        return Err(format!(
            "expected one input float32 [N, {N_IN}] and one output [N, {N_OUT}], found inputs \
             [{}] and outputs [{}]",
            names(&mut inputs.iter().copied()),
            names(&mut g.output.iter())
        ));
    }
    check_io("input", inputs[0], N_IN)?;
    check_io("output", &g.output[0], N_OUT)?;

    let mut vals: HashMap<&str, Val> = HashMap::new();
    for t in &g.initializer {
        vals.insert(t.name.as_str(), Val::Init(t));
    }
    let mut nodes = vec![DNode { op: Op::Input, width: N_IN }];
    vals.insert(inputs[0].name.as_str(), Val::Dyn(0));
    for n in &g.node {
        if !(n.domain.is_empty() || n.domain == "ai.onnx") {
            return Err(not_mlp(format!("op {}::{}", n.domain, n.op_type)));
        }
        let mut args = Vec::new();
        for name in &n.input {
            if name.is_empty() {
                args.push(None);
                continue;
            }
            let v = vals
                .get(name.as_str())
                .ok_or_else(|| not_mlp(format!("{} reads '{name}' before it is produced", n.op_type)))?;
            args.push(Some(match v {
                Val::Init(t) => Val::Const(read_tensor(t)?),
                v => v.clone(),
            }));
        }
        let out = eval_node(n, &args, &mut nodes)?;
        if let Some(o) = n.output.first() {
            vals.insert(o.as_str(), out);
        }
    }
    let out = match vals.get(g.output[0].name.as_str()) {
        Some(Val::Dyn(i)) => *i,
        Some(_) => return Err(not_mlp("the output is a constant")),
        None => return Err(not_mlp(format!("no node produces '{}'", g.output[0].name))),
    };
    let mut net = build(&nodes, out)?;
    if net.n_in() != N_IN || net.n_out() != N_OUT {
        return Err(format!(
            "the network maps [N, {}] to [N, {}]; expected [N, {N_IN}] -> [N, {N_OUT}]",
            net.n_in(),
            net.n_out()
        ));
    }
    use_exact_norms(model, &mut net);
    net.validate().map_err(|e| format!("invalid network: {e}"))?;
    Ok(net)
}

fn eval_node<'a>(
    n: &NodeProto,
    args: &[Option<Val<'a>>],
    nodes: &mut Vec<DNode>,
) -> std::result::Result<Val<'a>, String> {
    let op = n.op_type.as_str();
    let arg = |i: usize| -> std::result::Result<&Val, String> {
        args.get(i).and_then(Option::as_ref).ok_or_else(|| not_mlp(format!("{op} without input {i}")))
    };
    let dynamic = |i: usize| -> std::result::Result<usize, String> {
        match arg(i)? {
            Val::Dyn(d) => Ok(*d),
            _ => Err(not_mlp(format!("{op} on a constant input {i}"))),
        }
    };
    let constant = |i: usize| -> std::result::Result<&Const, String> {
        match arg(i)? {
            Val::Const(c) => Ok(c),
            _ => Err(not_mlp(format!("{op} with a non-constant input {i}"))),
        }
    };
    let push = |nodes: &mut Vec<DNode>, op: Op, width: usize| {
        nodes.push(DNode { op, width });
        Val::Dyn(nodes.len() - 1)
    };
    match op {
        "Identity" | "Dropout" => Ok(arg(0)?.clone()),
        "Constant" => {
            let a = n.attribute.first().ok_or_else(|| not_mlp("Constant without a value"))?;
            match (a.name.as_str(), a.t.as_ref()) {
                ("value", Some(t)) => Ok(Val::Const(read_tensor(t)?)),
                ("value_float", _) => Ok(Val::Const(Const { dims: vec![], data: vec![a.f] })),
                ("value_floats", _) => {
                    Ok(Val::Const(Const { dims: vec![a.floats.len() as i64], data: a.floats.clone() }))
                }
                (other, _) => Err(not_mlp(format!("Constant with attribute {other}"))),
            }
        }
        "Flatten" => {
            let src = dynamic(0)?;
            let axis = attr_i(n, "axis", 1)?;
            // Our values are [N, width]: only axis 1 (= -1) keeps them as they are.
            if axis != 1 && axis != -1 {
                return Err(not_mlp(format!("Flatten with axis {axis}")));
            }
            Ok(Val::Dyn(src))
        }
        "Relu" => {
            let src = dynamic(0)?;
            let w = nodes[src].width;
            Ok(push(nodes, Op::Relu { src }, w))
        }
        "Concat" => {
            let axis = attr_i(n, "axis", 1)?;
            if axis != 1 && axis != -1 {
                return Err(not_mlp(format!("Concat along axis {axis}")));
            }
            let srcs = (0..args.len()).map(dynamic).collect::<std::result::Result<Vec<_>, _>>()?;
            let w = srcs.iter().map(|s| nodes[*s].width).sum();
            Ok(push(nodes, Op::Concat { srcs }, w))
        }
        "MatMul" => {
            let src = dynamic(0)?;
            let wt = constant(1)?;
            let k = nodes[src].width;
            if wt.dims.len() != 2 || wt.dims[0] as usize != k {
                return Err(not_mlp(format!("MatMul of {k} columns with a weight of shape {:?}", wt.dims)));
            }
            let m = wt.dims[1] as usize;
            // PyTorch stores [in, out]; Dense wants [out, in].
            let w = (0..m * k).map(|i| wt.data[(i % k) * m + i / k] as f64).collect();
            Ok(push(nodes, Op::Linear { src, w, b: vec![0.0; m] }, m))
        }
        "Gemm" => {
            let src = dynamic(0)?;
            if attr_i(n, "transA", 0)? != 0 {
                return Err(not_mlp("Gemm with transA=1"));
            }
            let (alpha, beta) = (attr_f(n, "alpha", 1.0)? as f64, attr_f(n, "beta", 1.0)? as f64);
            let trans_b = attr_i(n, "transB", 0)? != 0;
            let wt = constant(1)?;
            let k = nodes[src].width;
            let ok = wt.dims.len() == 2 && wt.dims[if trans_b { 1 } else { 0 }] as usize == k;
            if !ok {
                return Err(not_mlp(format!(
                    "Gemm (transB={}) of {k} columns with a weight of shape {:?}",
                    trans_b as i32, wt.dims
                )));
            }
            let m = wt.dims[if trans_b { 0 } else { 1 }] as usize;
            let w = (0..m * k)
                .map(|i| {
                    let (r, c) = (i / k, i % k);
                    alpha * wt.data[if trans_b { i } else { c * m + r }] as f64
                })
                .collect();
            let b = match args.get(2).and_then(Option::as_ref) {
                None => vec![0.0; m],
                Some(_) => per_column(constant(2)?, m, "Gemm bias")?.into_iter().map(|v| beta * v).collect(),
            };
            Ok(push(nodes, Op::Linear { src, w, b }, m))
        }
        "Add" | "Sub" | "Mul" | "Div" => {
            let (d, c, const_first) = match (arg(0)?, arg(1)?) {
                (Val::Dyn(d), Val::Const(c)) => (*d, c, false),
                (Val::Const(c), Val::Dyn(d)) => (*d, c, true),
                (Val::Dyn(_), Val::Dyn(_)) => return Err(not_mlp(format!("{op} of two non-constant tensors"))),
                _ => return Err(not_mlp(format!("{op} of two constants"))),
            };
            let width = nodes[d].width;
            let v = per_column(c, width, op)?;
            let ops = match (op, const_first) {
                ("Add", _) => vec![Ew::Add(v)],
                ("Mul", _) => vec![Ew::Mul(v)],
                ("Sub", false) => vec![Ew::Sub(v)],
                // c - x
                ("Sub", true) => vec![Ew::Mul(vec![-1.0; width]), Ew::Add(v)],
                ("Div", false) if v.iter().all(|x| *x != 0.0) => vec![Ew::Div(v)],
                ("Div", false) => return Err(not_mlp("Div by a constant containing zero")),
                _ => return Err(not_mlp("Div of a constant by a non-constant tensor")),
            };
            // Merge with a preceding elementwise node so chains stay one node.
            let (src, mut all) = match &nodes[d].op {
                Op::Affine { src, ops } => (*src, ops.clone()),
                _ => (d, vec![]),
            };
            all.extend(ops);
            Ok(push(nodes, Op::Affine { src, ops: all }, width))
        }
        other => Err(not_mlp(format!("unsupported op {other} (node '{}')", n.name))),
    }
}

/// An [`Affine`] from elementwise ops applied to the raw input: `(x - mean) / std`.
fn input_affine(ops: &[Ew], width: usize) -> Affine {
    let mut a = Affine::identity(width);
    for op in ops {
        for j in 0..width {
            let (m, s) = (&mut a.mean[j], &mut a.std[j]);
            // (x - m) / s  op  c, rewritten as (x - m') / s'.
            match op {
                Ew::Sub(c) => *m += c[j] * *s,
                Ew::Add(c) => *m -= c[j] * *s,
                Ew::Div(c) => *s *= c[j],
                Ew::Mul(c) => *s /= c[j],
            }
        }
    }
    a
}

/// Composes `ops` (on columns `off..off+len` of `a`) into an output [`Affine`]: `z * std + mean`.
fn output_affine(ops: &[Ew], a: &mut Affine, off: usize, len: usize) {
    for op in ops {
        for j in 0..len {
            let (m, s) = (&mut a.mean[off + j], &mut a.std[off + j]);
            match op {
                Ew::Add(c) => *m += c[j],
                Ew::Sub(c) => *m -= c[j],
                Ew::Mul(c) => {
                    *m *= c[j];
                    *s *= c[j]
                }
                Ew::Div(c) => {
                    *m /= c[j];
                    *s /= c[j]
                }
            }
        }
    }
}

/// `x -> x * scale + shift` of elementwise ops.
fn as_scale_shift(ops: &[Ew], width: usize) -> (Vec<f64>, Vec<f64>) {
    let (mut s, mut t) = (vec![1.0; width], vec![0.0; width]);
    for op in ops {
        for j in 0..width {
            match op {
                Ew::Add(c) => t[j] += c[j],
                Ew::Sub(c) => t[j] -= c[j],
                Ew::Mul(c) => {
                    s[j] *= c[j];
                    t[j] *= c[j]
                }
                Ew::Div(c) => {
                    s[j] /= c[j];
                    t[j] /= c[j]
                }
            }
        }
    }
    (s, t)
}

/// A layer being assembled (f64 so that folding loses nothing before the final rounding).
#[derive(Clone)]
struct L64 {
    n_in: usize,
    n_out: usize,
    w: Vec<f64>,
    b: Vec<f64>,
}

impl L64 {
    fn dense(&self) -> Dense {
        Dense {
            n_in: self.n_in,
            n_out: self.n_out,
            w: self.w.iter().map(|v| *v as f32).collect(),
            b: self.b.iter().map(|v| *v as f32).collect(),
        }
    }
}

/// Folds a chain of ops into layers: a layer is Linear (+ elementwise ops, folded into it)
/// (+ Relu); elementwise ops after a Relu are folded into the next layer's input side.
#[derive(Clone, Default)]
struct Folder {
    layers: Vec<L64>,
    /// The last layer, still open for folding, and whether its Relu has been seen.
    cur: Option<(L64, bool)>,
    /// `x * scale + shift` to apply to the next layer's input.
    pending: Option<(Vec<f64>, Vec<f64>)>,
    /// The chain's input is already a Relu output (a head after the trunk).
    input_activated: bool,
}

impl Folder {
    fn step(&mut self, nodes: &[DNode], id: usize) -> std::result::Result<(), String> {
        match &nodes[id].op {
            Op::Linear { w, b, .. } => {
                let n_out = nodes[id].width;
                let n_in = w.len() / n_out.max(1);
                let mut new = L64 { n_in, n_out, w: w.clone(), b: b.clone() };
                match self.cur.take() {
                    Some((c, false)) => {
                        // Two linear maps in a row compose into one: W2 (W1 x + b1) + b2.
                        let mut w = vec![0.0; n_out * c.n_in];
                        for r in 0..n_out {
                            for k in 0..c.n_out {
                                let a = new.w[r * n_in + k];
                                for j in 0..c.n_in {
                                    w[r * c.n_in + j] += a * c.w[k * c.n_in + j];
                                }
                                new.b[r] += a * c.b[k];
                            }
                        }
                        new.w = w;
                        new.n_in = c.n_in;
                    }
                    prev => {
                        if let Some((s, t)) = self.pending.take() {
                            for r in 0..n_out {
                                let row = &mut new.w[r * n_in..(r + 1) * n_in];
                                for j in 0..n_in {
                                    new.b[r] += row[j] * t[j];
                                    row[j] *= s[j];
                                }
                            }
                        }
                        if let Some((p, _)) = prev {
                            self.layers.push(p);
                        }
                    }
                }
                self.cur = Some((new, false));
            }
            Op::Relu { .. } => {
                if let Some((_, act @ false)) = &mut self.cur {
                    *act = true;
                } else if self.pending.is_some() {
                    return Err(not_mlp("an elementwise op between a Relu and the next Relu"));
                } else if self.cur.is_none() && !self.input_activated {
                    return Err(not_mlp("Relu before the first layer"));
                }
                // Otherwise relu(relu(x)) = relu(x): nothing to do.
            }
            Op::Affine { ops, .. } => match &mut self.cur {
                Some((l, false)) => {
                    let (s, t) = as_scale_shift(ops, l.n_out);
                    for r in 0..l.n_out {
                        l.w[r * l.n_in..(r + 1) * l.n_in].iter_mut().for_each(|v| *v *= s[r]);
                        l.b[r] = l.b[r] * s[r] + t[r];
                    }
                }
                _ => {
                    let (s2, t2) = as_scale_shift(ops, nodes[id].width);
                    self.pending = Some(match self.pending.take() {
                        None => (s2, t2),
                        Some((s1, t1)) => (
                            s1.iter().zip(&s2).map(|(a, b)| a * b).collect(),
                            t1.iter().zip(&s2).zip(&t2).map(|((a, b), c)| a * b + c).collect(),
                        ),
                    });
                }
            },
            Op::Input | Op::Concat { .. } => return Err(not_mlp("Concat inside the network")),
        }
        Ok(())
    }

    /// Closes a chain that ends in the linear output layer.
    fn finish_output(mut self) -> std::result::Result<Vec<Dense>, String> {
        match self.cur.take() {
            Some((l, false)) => self.layers.push(l),
            Some((_, true)) => return Err(not_mlp("a Relu on the output")),
            None => return Err(not_mlp("a branch without a layer")),
        }
        Ok(self.layers.iter().map(L64::dense).collect())
    }
}

/// The source of a non-Input, non-Concat node.
fn src_of(op: &Op) -> Option<usize> {
    match op {
        Op::Affine { src, .. } | Op::Linear { src, .. } | Op::Relu { src } => Some(*src),
        Op::Input | Op::Concat { .. } => None,
    }
}

/// The chain of node ids from the input (excluded) to `end`.
fn path(nodes: &[DNode], end: usize) -> std::result::Result<Vec<usize>, String> {
    let mut p = vec![];
    let mut id = end;
    while !matches!(nodes[id].op, Op::Input) {
        p.push(id);
        id = src_of(&nodes[id].op).ok_or_else(|| not_mlp("Concat inside the network"))?;
    }
    p.reverse();
    Ok(p)
}

/// Turns the op graph ending in `out` into a [`Net`].
fn build(nodes: &[DNode], out: usize) -> std::result::Result<Net, String> {
    let n_out = nodes[out].width;
    let mut output_norm = Affine::identity(n_out);
    let peel = |id: usize| match &nodes[id].op {
        Op::Affine { src, ops } => (*src, ops.clone()),
        _ => (id, vec![]),
    };
    let (core, outer) = peel(out);
    // Branch ends and their own trailing elementwise ops (applied before `outer`).
    let mut ends = vec![];
    if let Op::Concat { srcs } = &nodes[core].op {
        let mut off = 0;
        for &s in srcs {
            let (e, ops) = peel(s);
            let w = nodes[s].width;
            output_affine(&ops, &mut output_norm, off, w);
            ends.push(e);
            off += w;
        }
    } else {
        ends.push(core);
    }
    output_affine(&outer, &mut output_norm, 0, n_out);

    let paths = ends.iter().map(|e| path(nodes, *e)).collect::<std::result::Result<Vec<_>, _>>()?;
    let shared = if paths.len() == 1 {
        paths[0].len()
    } else {
        (0..paths[0].len()).take_while(|&i| paths.iter().all(|p| p.get(i) == Some(&paths[0][i]))).count()
    };
    if paths.len() > 1 && paths.iter().any(|p| p.len() == shared) {
        return Err(not_mlp("a branch that is part of another branch"));
    }
    let trunk_ops = &paths[0][..shared];
    // Elementwise ops right after the input are the input normalisation.
    let (input_norm, trunk_ops) = match trunk_ops.first().map(|&i| &nodes[i].op) {
        Some(Op::Affine { ops, .. }) => (input_affine(ops, N_IN), &trunk_ops[1..]),
        _ => (Affine::identity(N_IN), trunk_ops),
    };
    let mut f = Folder::default();
    for &id in trunk_ops {
        f.step(nodes, id)?;
    }
    if paths.len() == 1 {
        return Ok(Net { trunk: f.finish_output()?, heads: vec![], input_norm, output_norm });
    }
    let mut heads_ops: Vec<&[usize]> = paths.iter().map(|p| &p[shared..]).collect();
    match f.cur.take() {
        None => {}
        Some((l, true)) => f.layers.push(l),
        Some((l, false)) => {
            // PyTorch-style `relu(trunk(x))` written once per branch: move the Relu up.
            let relu_first = |h: &&[usize]| matches!(nodes[h[0]].op, Op::Relu { .. });
            if !heads_ops.iter().all(relu_first) {
                return Err(not_mlp("branches start from a layer without Relu"));
            }
            heads_ops.iter_mut().for_each(|h| *h = &h[1..]);
            f.layers.push(l);
        }
    }
    let trunk: Vec<Dense> = f.layers.iter().map(L64::dense).collect();
    let mut heads = vec![];
    for ops in heads_ops {
        let mut h = Folder { pending: f.pending.clone(), input_activated: !trunk.is_empty(), ..Default::default() };
        for &id in ops {
            h.step(nodes, id)?;
        }
        heads.push(h.finish_output()?);
    }
    Ok(Net { trunk, heads, input_norm, output_norm })
}

/// Our exports carry the normalisation in f64 as metadata; use it when it agrees with what the
/// graph computes (so an edited graph wins over stale metadata).
fn use_exact_norms(model: &ModelProto, net: &mut Net) {
    let get = |key: &str| -> Option<Vec<f64>> {
        let e = model.metadata_props.iter().find(|e| e.key == key)?;
        e.value.split(',').map(|s| s.trim().parse().ok()).collect()
    };
    let close = |a: &[f64], b: &[f64]| {
        a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-6 * x.abs().max(y.abs()).max(1e-30))
    };
    let targets =
        [&mut net.input_norm.mean, &mut net.input_norm.std, &mut net.output_norm.mean, &mut net.output_norm.std];
    for (key, t) in META.iter().zip(targets) {
        if let Some(v) = get(key) {
            if close(&v, t) {
                *t = v;
            }
        }
    }
}
