//! Writing a [`Net`] as an ONNX graph of the contract (module doc of `onnx_io`).
use super::{INPUT_NAME, IR_VERSION, META, OPSET, OUTPUT_NAME};
use crate::net::{Dense, Net};
use crate::{FkError as CalibError, Result};
use onnx_protobuf::attribute_proto::AttributeType;
use onnx_protobuf::tensor_proto::DataType;
use onnx_protobuf::tensor_shape_proto::{dimension, Dimension};
use onnx_protobuf::{
    type_proto, AttributeProto, GraphProto, ModelProto, NodeProto, OperatorSetIdProto, StringStringEntryProto,
    TensorProto, TensorShapeProto, TypeProto, ValueInfoProto,
};
use protobuf::{EnumOrUnknown, Message, MessageField};
use std::path::Path;

// ---------------------------------------------------------------------------------------------
// Export

fn tensor(name: &str, dims: &[usize], data: &[f32]) -> TensorProto {
    TensorProto {
        name: name.into(),
        dims: dims.iter().map(|d| *d as i64).collect(),
        data_type: DataType::FLOAT as i32,
        raw_data: data.iter().flat_map(|v| v.to_le_bytes()).collect(),
        ..Default::default()
    }
}

fn attr_int(name: &str, v: i64) -> AttributeProto {
    AttributeProto { name: name.into(), type_: EnumOrUnknown::new(AttributeType::INT), i: v, ..Default::default() }
}

fn node(op: &str, inputs: &[&str], output: &str, attribute: Vec<AttributeProto>) -> NodeProto {
    NodeProto {
        op_type: op.into(),
        name: format!("{output}_{}", op.to_lowercase()),
        input: inputs.iter().map(|s| s.to_string()).collect(),
        output: vec![output.into()],
        attribute,
        ..Default::default()
    }
}

/// A float32 `[N, width]` graph input/output.
fn io(name: &str, width: usize) -> ValueInfoProto {
    let dim = |v| Dimension { value: Some(v), ..Default::default() };
    let shape = TensorShapeProto {
        dim: vec![dim(dimension::Value::DimParam("N".into())), dim(dimension::Value::DimValue(width as i64))],
        ..Default::default()
    };
    ValueInfoProto {
        name: name.into(),
        type_: MessageField::some(TypeProto {
            value: Some(type_proto::Value::TensorType(type_proto::Tensor {
                elem_type: DataType::FLOAT as i32,
                shape: MessageField::some(shape),
                ..Default::default()
            })),
            ..Default::default()
        }),
        ..Default::default()
    }
}

fn f32s(v: &[f64]) -> Vec<f32> {
    v.iter().map(|x| *x as f32).collect()
}

fn joined(v: &[f64]) -> String {
    // Rust's float formatting is the shortest string that parses back to the same f64.
    v.iter().map(f64::to_string).collect::<Vec<_>>().join(",")
}

/// The net as an ONNX model following the module's graph contract. Panics on an invalid net
/// (see [`Net::validate`]; [`export_onnx`] reports that as an error instead).
pub fn to_model(net: &Net) -> ModelProto {
    if let Err(e) = net.validate() {
        panic!("exporting an invalid net: {e}");
    }
    let mut nodes = Vec::new();
    let mut inits = Vec::new();
    let (ni, no) = (&net.input_norm, &net.output_norm);
    inits.push(tensor("input_mean", &[ni.len()], &f32s(&ni.mean)));
    inits.push(tensor("input_std", &[ni.len()], &f32s(&ni.std)));
    inits.push(tensor("output_std", &[no.len()], &f32s(&no.std)));
    inits.push(tensor("output_mean", &[no.len()], &f32s(&no.mean)));
    nodes.push(node("Sub", &[INPUT_NAME, "input_mean"], "theta_centred", vec![]));
    nodes.push(node("Div", &["theta_centred", "input_std"], "x", vec![]));

    // Appends Gemm (+ Relu) for `l`, named `prefix`; returns the output tensor's name.
    let mut layer = |l: &Dense, prefix: &str, input: &str, relu: bool| -> String {
        let (w, b) = (format!("{prefix}.weight"), format!("{prefix}.bias"));
        inits.push(tensor(&w, &[l.n_out, l.n_in], &l.w));
        inits.push(tensor(&b, &[l.n_out], &l.b));
        let z = format!("{prefix}.z");
        let attrs = vec![attr_int("transB", 1)];
        nodes.push(node("Gemm", &[input, &w, &b], &z, attrs));
        if !relu {
            return z;
        }
        let a = format!("{prefix}.a");
        nodes.push(node("Relu", &[&z], &a, vec![]));
        a
    };
    let mut cur = "x".to_string();
    for (i, l) in net.trunk.iter().enumerate() {
        let relu = i + 1 < net.trunk.len() || !net.heads.is_empty();
        cur = layer(l, &format!("trunk.{i}"), &cur, relu);
    }
    if !net.heads.is_empty() {
        let mut ends = Vec::new();
        for (h, head) in net.heads.iter().enumerate() {
            let mut c = cur.clone();
            for (i, l) in head.iter().enumerate() {
                c = layer(l, &format!("head{h}.{i}"), &c, i + 1 < head.len());
            }
            ends.push(c);
        }
        let ends: Vec<&str> = ends.iter().map(String::as_str).collect();
        nodes.push(node("Concat", &ends, "y", vec![attr_int("axis", 1)]));
        cur = "y".into();
    }
    nodes.push(node("Mul", &[&cur, "output_std"], "y_scaled", vec![]));
    nodes.push(node("Add", &["y_scaled", "output_mean"], OUTPUT_NAME, vec![]));

    let graph = GraphProto {
        name: "abvs_fk_mlp".into(),
        node: nodes,
        initializer: inits,
        input: vec![io(INPUT_NAME, net.n_in())],
        output: vec![io(OUTPUT_NAME, net.n_out())],
        doc_string: "raw link angles (deg) -> raw pose [alpha, beta, gamma (deg), x, y, z (mm)]".into(),
        ..Default::default()
    };
    let meta = [&ni.mean, &ni.std, &no.mean, &no.std];
    ModelProto {
        ir_version: IR_VERSION,
        opset_import: vec![OperatorSetIdProto { domain: String::new(), version: OPSET, ..Default::default() }],
        producer_name: "abvs-calib".into(),
        producer_version: env!("CARGO_PKG_VERSION").into(),
        graph: MessageField::some(graph),
        metadata_props: META
            .iter()
            .zip(meta)
            .map(|(k, v)| StringStringEntryProto { key: k.to_string(), value: joined(v), ..Default::default() })
            .collect(),
        ..Default::default()
    }
}

/// The ONNX file's bytes (see [`to_model`]).
pub fn onnx_to_bytes(net: &Net) -> Vec<u8> {
    to_model(net).write_to_bytes().expect("serialising an in-memory protobuf")
}

pub fn export_onnx(net: &Net, path: &Path) -> Result<()> {
    net.validate().map_err(|e| CalibError::model(path, format!("cannot export an invalid net: {e}")))?;
    std::fs::write(path, onnx_to_bytes(net)).map_err(|e| CalibError::io(path, e))
}
