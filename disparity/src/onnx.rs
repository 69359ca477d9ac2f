//! The ONNX stereo network engine, run by ONNX Runtime (`ort`, the library loaded at run time by
//! [`abvs_onnx`]).
//!
//! ONNX models follow the published HITNet exports' contract (PINTO model zoo), so those drop in: input
//! "input" `[1,2,H,W]` (left gray, right gray) or `[1,6,H,W]` (left RGB, right RGB), scaled /255; output
//! `[1,1,H,W]` (or `[1,H,W]`) left-view disparity in pixels. A model directory holds `model.onnx` and
//! `manifest.json` ([`crate::manifest`]); a bare .onnx file is accepted and described from its own
//! input/output shapes.
use std::path::{Path, PathBuf};

use crate::engine::{check_sizes, DisparityEngine};
use crate::error::{DisparityError, Result};
use crate::manifest::{DisparityManifest, DISPARITY_FORMAT};

/// ONNX stereo network through ONNX Runtime; input and output tensors are allocated once and bound.
pub struct OnnxEngine {
    name: String,
    /// The model's manifest.
    pub manifest: DisparityManifest,
    /// The ONNX file.
    pub path: PathBuf,
    session: ort::session::Session,
    input: ort::value::Tensor<f32>,
    /// Pre-allocated output, bound to the model's output: ONNX Runtime writes the disparity straight into it.
    output: ort::value::Tensor<f32>,
    binding: ort::session::IoBinding,
    rgb: bool,
}

impl OnnxEngine {
    /// Loads a model directory (manifest.json + model) or a bare .onnx file; `threads` intra-op threads.
    pub fn load(path: &Path, threads: usize) -> Result<OnnxEngine> {
        let (manifest, model_path) = if path.is_dir() {
            let mp = path.join("manifest.json");
            let m = DisparityManifest::load(path)?;
            let f = path.join(&m.file);
            if let Some(h) = &m.onnx_sha256 {
                abvs_fk::hash::verify_sha256(&f, &mp, h).map_err(|e| match e {
                    abvs_fk::FkError::Model { path, msg } => DisparityError::Model { path, msg },
                    source => DisparityError::Hash { path: path.to_path_buf(), source },
                })?;
            }
            (Some(m), f)
        } else {
            (None, path.to_path_buf())
        };
        let session = abvs_onnx::session(&model_path, threads)
            .map_err(|source| DisparityError::OnnxRuntime { path: path.to_path_buf(), source })?;
        let (mut manifest, shape) =
            describe(&session, manifest).map_err(|m| DisparityError::Model { path: model_path.clone(), msg: m })?;
        if manifest.file.is_empty() {
            manifest.file = model_path.file_name().map(|f| f.to_string_lossy().into_owned()).unwrap_or_default();
        }
        let cerr = |source: ort::Error| DisparityError::Onnx { path: model_path.clone(), source };
        let input = ort::value::Tensor::<f32>::new(session.allocator(), shape).map_err(cerr)?;
        // the output buffer has the model's declared rank ([1,1,H,W] or [1,H,W])
        let (hh, ww) = (manifest.height as usize, manifest.width as usize);
        let out_rank = session.outputs()[0].dtype().tensor_shape().map(|s| s.len()).unwrap_or(4);
        let mut output = if out_rank == 4 {
            ort::value::Tensor::<f32>::new(session.allocator(), [1usize, 1, hh, ww])
        } else {
            ort::value::Tensor::<f32>::new(session.allocator(), [1usize, hh, ww])
        }
        .map_err(cerr)?;
        let mut binding = session.create_binding().map_err(cerr)?;
        binding.bind_input(manifest.input_name.clone(), &input).map_err(cerr)?;
        binding.bind_output(manifest.output_name.clone(), &mut output).map_err(cerr)?;
        let rgb = manifest.input_layout == "rgb6";
        Ok(OnnxEngine {
            name: format!("onnx:{}", manifest.variant),
            manifest,
            path: model_path,
            session,
            input,
            output,
            binding,
            rgb,
        })
    }
}

/// Checks a session against the disparity contract and fills in what the manifest does not say.
fn describe(
    session: &ort::session::Session,
    manifest: Option<DisparityManifest>,
) -> std::result::Result<(DisparityManifest, [usize; 4]), String> {
    let inputs = session.inputs();
    if inputs.len() != 1 {
        return Err(format!(
            "a disparity model takes one input [1,2,H,W] or [1,6,H,W]; this one takes {} ({})",
            inputs.len(),
            inputs.iter().map(|i| i.name().to_string()).collect::<Vec<_>>().join(", ")
        ));
    }
    let i = &inputs[0];
    if i.dtype().tensor_type() != Some(ort::value::TensorElementType::Float32) {
        return Err(format!("input `{}` is {:?}, expected float32", i.name(), i.dtype()));
    }
    let shape: Vec<i64> = i.dtype().tensor_shape().map(|s| s.to_vec()).unwrap_or_default();
    if shape.len() != 4 || shape[0] != 1 || !(shape[1] == 2 || shape[1] == 6) || shape[2] <= 0 || shape[3] <= 0 {
        return Err(format!(
            "input `{}` has shape {shape:?}; expected a static [1,2,H,W] (gray pair) or [1,6,H,W] (RGB pair)",
            i.name()
        ));
    }
    let outputs = session.outputs();
    if outputs.is_empty() {
        return Err("model has no output".into());
    }
    let o = &outputs[0];
    let oshape: Vec<i64> = o.dtype().tensor_shape().map(|s| s.to_vec()).unwrap_or_default();
    let (h, w) = (shape[2], shape[3]);
    let ok_out = oshape == [1, 1, h, w] || oshape == [1, h, w];
    if !ok_out {
        return Err(format!("output `{}` has shape {oshape:?}; expected [1,1,{h},{w}] disparity", o.name()));
    }
    let layout = if shape[1] == 2 { "gray2" } else { "rgb6" };
    let m = match manifest {
        Some(m) => {
            if m.input_name != i.name() || m.output_name != o.name() {
                return Err(format!(
                    "manifest names input `{}` / output `{}`, the model has `{}` / `{}`",
                    m.input_name,
                    m.output_name,
                    i.name(),
                    o.name()
                ));
            }
            if m.input_layout != layout || m.width as i64 != w || m.height as i64 != h {
                return Err(format!(
                    "manifest says {} {}x{}, the model takes {layout} {w}x{h}",
                    m.input_layout, m.width, m.height
                ));
            }
            m
        }
        None => DisparityManifest {
            format: DISPARITY_FORMAT.into(),
            variant: "external".into(),
            file: String::new(),
            input_name: i.name().into(),
            input_layout: layout.into(),
            input_scale: 1.0 / 255.0,
            width: w as u32,
            height: h as u32,
            max_disparity: w as f64 / 4.0,
            output_name: o.name().into(),
            metrics: serde_json::Value::Null,
            training: serde_json::Value::Null,
            onnx_sha256: None,
            refine_base: None,
        },
    };
    Ok((m, [1, shape[1] as usize, h as usize, w as usize]))
}

impl DisparityEngine for OnnxEngine {
    fn name(&self) -> &str {
        &self.name
    }
    fn size(&self) -> (u32, u32) {
        (self.manifest.width, self.manifest.height)
    }
    fn max_disparity(&self) -> f64 {
        self.manifest.max_disparity
    }
    fn compute(&mut self, left: &[u8], right: &[u8], out: &mut [f32]) -> Result<()> {
        check_sizes(&self.name, self.size(), left, right, out)?;
        let n = left.len();
        let scale = self.manifest.input_scale as f32;
        let (_, data) = self.input.extract_tensor_mut();
        if self.rgb {
            // gray images replicated into the three colour planes of each eye
            for c in 0..3 {
                for (d, s) in data[c * n..(c + 1) * n].iter_mut().zip(left) {
                    *d = *s as f32 * scale;
                }
                for (d, s) in data[(3 + c) * n..(4 + c) * n].iter_mut().zip(right) {
                    *d = *s as f32 * scale;
                }
            }
        } else {
            for (d, s) in data[..n].iter_mut().zip(left) {
                *d = *s as f32 * scale;
            }
            for (d, s) in data[n..2 * n].iter_mut().zip(right) {
                *d = *s as f32 * scale;
            }
        }
        // The C API's RunWithBinding directly: `Session::run_binding` wraps the (already bound) outputs in a
        // freshly allocated map every call, and the pipeline must not allocate per frame.
        use ort::AsPointer;
        let api = ort::api();
        // SAFETY: session and binding are live for the call; input and output tensors bound to it are owned by
        // self and not moved; ORT writes the output into our pre-allocated tensor.
        let status =
            unsafe { (api.RunWithBinding)(self.session.ptr().cast_mut(), std::ptr::null(), self.binding.ptr()) };
        if !status.0.is_null() {
            // SAFETY: a non-null status carries a NUL-terminated message; we release it once read.
            let msg = unsafe {
                let m = std::ffi::CStr::from_ptr((api.GetErrorMessage)(status.0)).to_string_lossy().into_owned();
                (api.ReleaseStatus)(status.0);
                m
            };
            return Err(DisparityError::Model { path: self.path.clone(), msg: format!("inference failed: {msg}") });
        }
        let (_, disp) = self.output.extract_tensor();
        let max = self.manifest.max_disparity as f32 * 1.5;
        for (o, d) in out.iter_mut().zip(disp) {
            // a network always answers; values outside its trained range are not disparities
            *o = if d.is_finite() && *d >= 0.0 && *d <= max { *d } else { f32::NAN };
        }
        Ok(())
    }
}
