//! `Net`s as ONNX files, and plain-MLP ONNX graphs (ours or trained elsewhere) as `Net`s.
//!
//! # Graph contract
//! This is how a network trained elsewhere (e.g. PyTorch + `torch.onnx.export`) drops in:
//! - one input [`INPUT_NAME`] `"theta"`: float32 `[N, 3]`, raw link angles in degrees;
//! - one output [`OUTPUT_NAME`] `"pose"`: float32 `[N, 6]`, raw `[alpha, beta, gamma (deg),
//!   x, y, z (mm)]`; `N` is dynamic (`dim_param "N"`);
//! - the normalisation is inside the graph: `Sub(mean) -> Div(std)` at the input,
//!   `Mul(std) -> Add(mean)` at the output (constant initializers of shape `[3]`/`[6]`);
//! - layers are `Gemm(transB=1)` (weight `[out, in]`) + `Relu`; a net with branches has a
//!   shared trunk whose last `Relu` output feeds every branch; the branches end in a linear
//!   layer and are joined with `Concat(axis=1)` in output order (M2: `[rotation, translation]`).
//!
//! [`export_onnx`] writes exactly that (opset 17, IR version 8), plus the normalisation in
//! full f64 precision as metadata (`abvs.input_mean`, ...) so that an import gives back the
//! identical `Net`; the graph itself computes in f32.
//!
//! [`import_onnx`] reads any graph that is an MLP in disguise: `Gemm` (any `transB`, `alpha`,
//! `beta`, bias of shape `[out]`/`[1, out]`/scalar or absent), `MatMul` with a constant
//! `[in, out]` weight (PyTorch's layout) followed by `Add(bias)`, `Relu`, `Identity`,
//! `Dropout` (inference: identity), `Flatten(axis=1)`, `Concat(axis=1)` of the branches, and
//! elementwise `Add`/`Sub`/`Mul`/`Div` with a constant (scalar or per column) anywhere: before
//! the first layer they become the input normalisation, after the last one the output
//! normalisation, between layers they are folded into the weights. Constants may be
//! initializers or `Constant` nodes. The input name is not checked (only its shape), so any
//! single-input graph works natively; [`crate::model`] additionally needs the name `"theta"`
//! for graphs it has to run through ONNX Runtime.
//!
//! Errors name the file: a graph that is not such an MLP (an unsupported op, a non-MLP
//! topology, non-float constants, external data, ...) is [`FkError::NotMlp`], so that the
//! caller can fall back to running it through ONNX Runtime; other faults are [`FkError::Model`]: wrong declared input/output shapes give a message naming the
//! expected and the found shape; unreadable bytes give `"not an ONNX model: ..."`.
//!
//! [`FkError::NotMlp`]: crate::FkError::NotMlp
//! [`FkError::Model`]: crate::FkError::Model
mod export;
mod import;

pub use export::{export_onnx, onnx_to_bytes, to_model};
pub use import::{import_onnx, import_onnx_bytes};

pub const INPUT_NAME: &str = "theta";
pub const OUTPUT_NAME: &str = "pose";
pub const OPSET: i64 = 17;
pub const IR_VERSION: i64 = 8;
/// Start of the message of every "this graph is not something [`crate::net::Net`] can represent" error.
pub const NOT_MLP: &str = "not a plain MLP graph";

const N_IN: usize = 3;
const N_OUT: usize = 6;
const META: [&str; 4] = ["abvs.input_mean", "abvs.input_std", "abvs.output_mean", "abvs.output_std"];
