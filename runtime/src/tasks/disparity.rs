//! Disparity engines behind one interface: an ONNX stereo network run by ONNX Runtime (`ort`), and OpenCV's
//! StereoSGBM (its parallel SGBM_3WAY mode) as the classical second engine; [`engine`] builds any of them by
//! name, the network-based [`super::disparity_census`] and [`super::disparity_fused`] included.
//!
//! ONNX models follow the published HITNet exports' contract (PINTO model zoo), so those drop in: input
//! "input" `[1,2,H,W]` (left gray, right gray) or `[1,6,H,W]` (left RGB, right RGB), scaled /255; output
//! `[1,1,H,W]` (or `[1,H,W]`) left-view disparity in pixels. A model directory holds `model.onnx` and
//! `manifest.json` ("abvs-disparity-model/1": layout, resolution, max disparity, training recipe, metrics);
//! a bare .onnx file is accepted and described from its own input/output shapes.
//! Invalid disparities are NaN (never 0, which is a valid disparity at infinity).
use std::path::{Path, PathBuf};

use opencv::core::{Mat, Scalar};
use opencv::prelude::*;
use serde::{Deserialize, Serialize};

use abvs_runtime_core::error::{Result, RuntimeError};
use abvs_runtime_core::messages::Work;
use abvs_runtime_core::stage::{Stage, StageContext};

use super::confidence::LrCheck;
use abvs_runtime_core::params::CheckConfig;

/// The format tag of a disparity model's manifest.json.
pub const DISPARITY_FORMAT: &str = "abvs-disparity-model/1";

/// manifest.json of a disparity model directory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DisparityManifest {
    /// The format tag, [`DISPARITY_FORMAT`].
    pub format: String,
    /// The model's name (e.g. `hitnet-s`).
    pub variant: String,
    /// The ONNX file, relative to the model directory.
    pub file: String,
    /// The network's input tensor.
    pub input_name: String,
    /// "gray2" (`[1,2,H,W]`) or "rgb6" (`[1,6,H,W]`).
    pub input_layout: String,
    /// Input scale: pixel levels are multiplied by this.
    pub input_scale: f64,
    /// Input width the network was exported at (px).
    pub width: u32,
    /// Input height (px).
    pub height: u32,
    /// Largest disparity the network outputs (px).
    pub max_disparity: f64,
    /// The network's output tensor.
    pub output_name: String,
    /// What the model scored at training (free form).
    #[serde(default)]
    pub metrics: serde_json::Value,
    /// How the model was trained (free form).
    #[serde(default)]
    pub training: serde_json::Value,
    /// Hex SHA-256 of the model file, checked on load (a damaged model would silently change the depth).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub onnx_sha256: Option<String>,
    /// The network census-refine runs in this one's place (a sibling directory's name). The shipped hitnet-m
    /// names `hitnet-s`: at 640x480, hitnet-s and SGBM at its 320x240, refined there, beat hitnet-m's weights
    /// refined at 640x480 on real pairs at half the CPU (models/hitnet/README.md).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub refine_base: Option<String>,
}

/// The network census-refine runs for the model at `path`: the sibling its manifest names as `refine_base`,
/// else the model itself (an .onnx file, or a manifest without one).
pub fn refine_base(path: &Path) -> Result<PathBuf> {
    let mp = path.join("manifest.json");
    if !path.is_dir() || !mp.is_file() {
        return Ok(path.to_path_buf());
    }
    let text =
        std::fs::read_to_string(&mp).map_err(|e| RuntimeError::Model { path: mp.clone(), msg: e.to_string() })?;
    let m: DisparityManifest = serde_json::from_str(&text)
        .map_err(|e| RuntimeError::Model { path: mp.clone(), msg: format!("bad manifest: {e}") })?;
    match m.refine_base {
        None => Ok(path.to_path_buf()),
        Some(name) => {
            let mut parts = Path::new(&name).components();
            match (parts.next(), parts.next()) {
                (Some(std::path::Component::Normal(_)), None) => {}
                _ => {
                    return Err(RuntimeError::Model {
                        path: mp,
                        msg: format!("bad manifest: `refine_base` `{name}`: must be a sibling directory's name"),
                    })
                }
            }
            // `path` may end in a separator or be relative without a parent: go through its file name
            let dir =
                std::path::absolute(path).map_err(|e| RuntimeError::Model { path: mp.clone(), msg: e.to_string() })?;
            Ok(dir.parent().unwrap_or(Path::new("/")).join(name))
        }
    }
}

/// A stereo matcher on rectified 8-bit gray images of a fixed size.
pub trait DisparityEngine: Send {
    /// The engine's name in statistics and logs.
    fn name(&self) -> &str;
    /// The resolution the engine runs at.
    fn size(&self) -> (u32, u32);
    /// Largest disparity the engine searches (px).
    fn max_disparity(&self) -> f64;
    /// Left-view disparity (px) into `out` (width*height); NaN where there is none.
    fn compute(&mut self, left: &[u8], right: &[u8], out: &mut [f32]) -> Result<()>;
    /// The last [`DisparityEngine::compute`]'s per-pixel confidence in [0, 1] and the reason code of each
    /// (`super::confidence::reason`), when the engine computes them as it goes (census-refine:
    /// [`super::census_confidence`]); width*height each.
    fn confidence(&self) -> Option<(&[f32], &[u8])> {
        None
    }
}

fn check_sizes(name: &str, (w, h): (u32, u32), left: &[u8], right: &[u8], out: &[f32]) -> Result<()> {
    let n = (w * h) as usize;
    if left.len() != n || right.len() != n || out.len() != n {
        return Err(RuntimeError::Invalid(format!(
            "{name}: images of {} / {} pixels and output of {} for a {w}x{h} engine",
            left.len(),
            right.len(),
            out.len()
        )));
    }
    Ok(())
}

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
        let err = |msg: String| RuntimeError::Model { path: path.to_path_buf(), msg };
        let (manifest, model_path) = if path.is_dir() {
            let mp = path.join("manifest.json");
            let text = std::fs::read_to_string(&mp)
                .map_err(|e| RuntimeError::Model { path: mp.clone(), msg: e.to_string() })?;
            let m: DisparityManifest = serde_json::from_str(&text)
                .map_err(|e| RuntimeError::Model { path: mp.clone(), msg: format!("bad manifest: {e}") })?;
            if m.format != DISPARITY_FORMAT {
                return Err(RuntimeError::Model {
                    path: mp,
                    msg: format!("format `{}`, expected `{DISPARITY_FORMAT}`", m.format),
                });
            }
            // the model file is named relative to the manifest and stays in its directory
            abvs_runtime_core::session::check_inside(&m.file)
                .map_err(|e| RuntimeError::Model { path: mp.clone(), msg: format!("bad manifest: `file`: {e}") })?;
            let f = path.join(&m.file);
            if let Some(h) = &m.onnx_sha256 {
                abvs_fk::hash::verify_sha256(&f, &mp, h).map_err(|e| match e {
                    abvs_fk::FkError::Model { path, msg } => RuntimeError::Model { path, msg },
                    e => err(e.to_string()),
                })?;
            }
            (Some(m), f)
        } else {
            (None, path.to_path_buf())
        };
        let session = abvs_onnx::session(&model_path, threads).map_err(|e| err(e.to_string()))?;
        let (mut manifest, shape) =
            describe(&session, manifest).map_err(|m| RuntimeError::Model { path: model_path.clone(), msg: m })?;
        if manifest.file.is_empty() {
            manifest.file = model_path.file_name().map(|f| f.to_string_lossy().into_owned()).unwrap_or_default();
        }
        let cerr = |e: ort::Error| RuntimeError::Model { path: model_path.clone(), msg: e.to_string() };
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
            return Err(RuntimeError::Model { path: self.path.clone(), msg: format!("inference failed: {msg}") });
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

/// OpenCV's worker threads (one pool per process: SGBM_3WAY's stripes, remap): the same budget as the
/// network's intra-op threads, so that the two engines are compared and deployed on equal terms.
pub fn set_opencv_threads(threads: usize) -> Result<()> {
    opencv::core::set_num_threads(threads.max(1) as i32)
        .map_err(|e| RuntimeError::Invalid(format!("opencv threads: {}", e.message)))
}

/// OpenCV StereoSGBM with settings for our rectified eyes, in MODE_SGBM_3WAY: parallel stripes on OpenCV's
/// pool ([`set_opencv_threads`]) with MODE_SGBM's accuracy (plain MODE_SGBM runs on one thread).
pub struct SgbmEngine {
    width: u32,
    height: u32,
    num_disparities: i32,
    sgbm: opencv::core::Ptr<opencv::calib3d::StereoSGBM>,
    disp: Mat,
}

impl SgbmEngine {
    /// `max_disparity` is rounded up to OpenCV's multiple of 16.
    pub fn new(width: u32, height: u32, max_disparity: f64) -> Result<SgbmEngine> {
        Self::with_block(width, height, max_disparity, 5)
    }

    /// With a `block` x `block` matching window (P1 and P2 scale with its area, as OpenCV recommends).
    pub fn with_block(width: u32, height: u32, max_disparity: f64, block: i32) -> Result<SgbmEngine> {
        let cv = |e: opencv::Error| RuntimeError::Invalid(format!("sgbm: {}", e.message));
        let num = ((max_disparity.ceil() as i32 + 15) / 16 * 16).max(16);
        let sgbm = opencv::calib3d::StereoSGBM::create(
            0,
            num,
            block,
            8 * block * block,
            32 * block * block,
            1,
            63,
            10,
            100,
            2,
            opencv::calib3d::StereoSGBM_MODE_SGBM_3WAY,
        )
        .map_err(cv)?;
        let disp =
            Mat::new_rows_cols_with_default(height as i32, width as i32, opencv::core::CV_16SC1, Scalar::all(0.0))
                .map_err(cv)?;
        Ok(SgbmEngine { width, height, num_disparities: num, sgbm, disp })
    }

    /// Changes the search range (px, a positive multiple of 16); the left `range` columns get no match.
    pub fn set_range(&mut self, range: i32) -> Result<()> {
        use opencv::calib3d::StereoMatcherTrait;
        if range < 16 || range % 16 != 0 {
            return Err(RuntimeError::Invalid(format!("sgbm: range {range} is not a positive multiple of 16")));
        }
        self.sgbm.set_num_disparities(range).map_err(|e| RuntimeError::Invalid(format!("sgbm: {}", e.message)))?;
        self.num_disparities = range;
        Ok(())
    }
}

impl DisparityEngine for SgbmEngine {
    fn name(&self) -> &str {
        "sgbm"
    }
    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }
    fn max_disparity(&self) -> f64 {
        self.num_disparities as f64
    }
    fn compute(&mut self, left: &[u8], right: &[u8], out: &mut [f32]) -> Result<()> {
        check_sizes("sgbm", self.size(), left, right, out)?;
        let cv = |e: opencv::Error| RuntimeError::Invalid(format!("sgbm: {}", e.message));
        let (w, h) = (self.width as i32, self.height as i32);
        let l = Mat::new_rows_cols_with_data(h, w, left).map_err(cv)?;
        let r = Mat::new_rows_cols_with_data(h, w, right).map_err(cv)?;
        use opencv::calib3d::StereoMatcherTrait;
        self.sgbm.compute(&l, &r, &mut self.disp).map_err(cv)?;
        let d = self.disp.data_typed::<i16>().map_err(cv)?;
        for (o, v) in out.iter_mut().zip(d) {
            // fixed point with 4 fractional bits; negative = no match
            *o = if *v < 0 { f32::NAN } else { *v as f32 / 16.0 };
        }
        Ok(())
    }
}

/// The engines [`engine`] builds, by name (`config::EngineKind::as_str`).
pub const ENGINES: [&str; 4] = ["census-refine", "onnx", "sgbm", "fused"];

/// Builds an engine by name ([`ENGINES`]): "sgbm", or "onnx" / "census-refine" / "fused" with a model path;
/// `threads` for ONNX Runtime and OpenCV alike.
pub fn engine(
    kind: &str,
    model: Option<&Path>,
    size: (u32, u32),
    max_disparity: f64,
    threads: usize,
) -> Result<Box<dyn DisparityEngine>> {
    let load = || {
        let p = model.ok_or_else(|| RuntimeError::Invalid(format!("engine {kind} needs a model")))?;
        OnnxEngine::load(p, threads).map(|e| (p, e))
    };
    set_opencv_threads(threads)?;
    match kind {
        "sgbm" => Ok(Box::new(SgbmEngine::new(size.0, size.1, max_disparity)?)),
        "onnx" => {
            let (p, e) = load()?;
            if e.size() != size {
                return Err(RuntimeError::Model {
                    path: p.to_path_buf(),
                    msg: format!("model runs at {}x{}, the pipeline at {}x{}", e.size().0, e.size().1, size.0, size.1),
                });
            }
            Ok(Box::new(e))
        }
        // these two resize the network's input, so any model size goes
        "census-refine" => {
            let p = refine_base(model.ok_or_else(|| RuntimeError::Invalid(format!("engine {kind} needs a model")))?)?;
            let net = OnnxEngine::load(&p, threads)?;
            Ok(Box::new(super::disparity_census::CensusRefineEngine::new(net, size.0, size.1)?))
        }
        "fused" => Ok(Box::new(super::disparity_fused::FusedEngine::new(load()?.1, size.0, size.1)?)),
        other => Err(RuntimeError::Invalid(format!("unknown disparity engine `{other}` ({})", ENGINES.join(" | ")))),
    }
}

/// The disparity stage: left-view disparity ([`Work::disparity`]) of the rectified pair, by any engine. With
/// an engine that scores its own pixels ([`DisparityEngine::confidence`]: census-refine) the confidence and
/// reasons go into [`Work::confidence`] / [`Work::reason`] and the validity mask drops (NaN) every pixel
/// below `min_confidence` (0: none, the dense map bit for bit). With a left-right check
/// ([`super::confidence`]) its confidence replaces the engine's and, if asked, the inconsistent pixels are
/// invalidated too.
pub struct DisparityStage {
    /// The engine.
    pub engine: Box<dyn DisparityEngine>,
    check: Option<LrCheck>,
    min_confidence: f32,
}

impl DisparityStage {
    /// The stage with an engine, no left-right check and no mask.
    pub fn new(engine: Box<dyn DisparityEngine>) -> Self {
        DisparityStage { engine, check: None, min_confidence: 0.0 }
    }

    /// The stage with the left-right check `cfg` (none when `cfg` enables nothing) and no mask.
    pub fn with_check(engine: Box<dyn DisparityEngine>, cfg: CheckConfig) -> Result<Self> {
        let check = if cfg.enabled() { Some(LrCheck::new(cfg)?) } else { None };
        Ok(DisparityStage { engine, check, min_confidence: 0.0 })
    }

    /// The validity mask's threshold in [0, 1] (refused outside it).
    pub fn with_min_confidence(mut self, c: f32) -> Result<Self> {
        if !(0.0..=1.0).contains(&c) {
            return Err(RuntimeError::Invalid(format!("min_confidence {c} must be in [0, 1]")));
        }
        self.min_confidence = c;
        Ok(self)
    }
}

impl Stage for DisparityStage {
    fn name(&self) -> &'static str {
        "disparity"
    }

    fn bottleneck(&self) -> bool {
        true
    }

    fn start(&mut self, ctx: &mut StageContext) -> Result<()> {
        let out = (ctx.out.width, ctx.out.height);
        let e = &self.engine;
        if e.size() != out {
            return Err(RuntimeError::Invalid(format!(
                "disparity engine {} runs at {}x{}, the pipeline at {}x{}",
                e.name(),
                e.size().0,
                e.size().1,
                out.0,
                out.1
            )));
        }
        if let Some(c) = &mut self.check {
            c.start(out.0, out.1);
        }
        Ok(())
    }

    fn prepare_work(&self, w: &mut Work) {
        if let Some(c) = &self.check {
            c.prepare_work(w);
        }
        if self.engine.confidence().is_some() {
            w.confidence = vec![0.0; w.disparity.len()];
            w.reason = vec![0; w.disparity.len()];
        }
    }

    fn process(&mut self, w: &mut Work) -> Result<()> {
        if w.motion.gated {
            // the motion gate: too blurred to match, so not matched (saves the engine's time during saccades)
            w.disparity.fill(f32::NAN);
            w.confidence.fill(0.0);
            w.reason.fill(super::confidence::reason::NO_ESTIMATE);
            return Ok(());
        }
        let Work { rectified, disparity, confidence, reason, .. } = w;
        self.engine.compute(&rectified.left, &rectified.right, disparity)?;
        if let Some((conf, why)) = self.engine.confidence() {
            mask(conf, why, &rectified.valid, self.min_confidence, disparity, confidence, reason)?;
        }
        if let Some(c) = &mut self.check {
            c.process(self.engine.as_mut(), w)?;
        }
        Ok(())
    }

    fn failure(&self, _e: &RuntimeError) -> &'static str {
        "disparity engine failed"
    }
}

/// The engine's confidence `conf` and reasons `why` into the frame's (0 and `NO_ESTIMATE` where the
/// rectified pixel does not see the raw image), then the validity mask at `min`
/// ([`super::census_confidence::mask`]).
fn mask(
    conf: &[f32],
    why: &[u8],
    valid: &[u8],
    min: f32,
    disparity: &mut [f32],
    out_conf: &mut [f32],
    out_why: &mut [u8],
) -> Result<()> {
    let n = disparity.len();
    if conf.len() != n || why.len() != n || valid.len() != n || out_conf.len() != n || out_why.len() != n {
        return Err(RuntimeError::Invalid("validity mask: buffers not sized (not started?)".into()));
    }
    for i in 0..n {
        (out_conf[i], out_why[i]) =
            if valid[i] == 0 { (0.0, super::confidence::reason::NO_ESTIMATE) } else { (conf[i], why[i]) };
    }
    super::census_confidence::mask(out_conf, min, disparity, out_why);
    Ok(())
}
