//! The disparity stage: the runtime's wrapper of an `abvs_disparity` engine (the engines, their confidence,
//! the left-right check and the validity mask live in that crate; this module only moves a frame's buffers
//! through them and turns their errors into the runtime's).
use abvs_disparity::confidence::{mask_into, reason, LrCheck};
use abvs_disparity::engine::DisparityEngine;
use abvs_disparity::DisparityError;
use abvs_runtime_core::params::CheckConfig;

use abvs_runtime_core::error::{Result, RuntimeError};
use abvs_runtime_core::messages::Work;
use abvs_runtime_core::stage::{Stage, StageContext};

/// A disparity error as the runtime's, its message unchanged: a model's fault names its file
/// ([`RuntimeError::Model`]), a data file's too ([`RuntimeError::File`]), every other is
/// [`RuntimeError::Invalid`]. (The runtime's error keeps no source: it compares by value.)
pub fn runtime_error(e: DisparityError) -> RuntimeError {
    match e {
        DisparityError::Model { path, msg } => RuntimeError::Model { path, msg },
        DisparityError::Read { path, source } => RuntimeError::Model { path, msg: source.to_string() },
        DisparityError::Manifest { path, source } => {
            RuntimeError::Model { path, msg: format!("bad manifest: {source}") }
        }
        DisparityError::Onnx { path, source } => RuntimeError::Model { path, msg: source.to_string() },
        DisparityError::OnnxRuntime { path, source } => RuntimeError::Model { path, msg: source.to_string() },
        DisparityError::Hash { path, source } => RuntimeError::Model { path, msg: source.to_string() },
        DisparityError::Format { path, msg } => RuntimeError::File { path, line: None, msg },
        DisparityError::Write { path, source } => RuntimeError::File { path, line: None, msg: source.to_string() },
        DisparityError::OpenCv { what, source } => RuntimeError::Invalid(format!("{what}: {}", source.message)),
        DisparityError::Invalid(msg) => RuntimeError::Invalid(msg),
    }
}

/// The disparity stage: left-view disparity ([`Work::disparity`]) of the rectified pair, by any engine. With
/// an engine that scores its own pixels ([`DisparityEngine::confidence`]: census-refine) the confidence and
/// reasons go into [`Work::confidence`] / [`Work::reason`] and the validity mask drops (NaN) every pixel
/// below `min_confidence` (0: none, the dense map bit for bit). With a left-right check
/// ([`abvs_disparity::confidence::LrCheck`]) its confidence replaces the engine's and, if asked, the
/// inconsistent pixels are invalidated too.
pub struct DisparityStage {
    /// The engine.
    pub engine: Box<dyn DisparityEngine>,
    check: Option<LrCheck>,
    min_confidence: f32,
    keep_dense: bool,
}

impl DisparityStage {
    /// The stage with an engine, no left-right check and no mask.
    pub fn new(engine: Box<dyn DisparityEngine>) -> Self {
        DisparityStage { engine, check: None, min_confidence: 0.0, keep_dense: false }
    }

    /// The stage with the left-right check `cfg` (none when `cfg` enables nothing) and no mask.
    pub fn with_check(engine: Box<dyn DisparityEngine>, cfg: CheckConfig) -> Result<Self> {
        let check = if cfg.enabled() { Some(LrCheck::new(cfg).map_err(runtime_error)?) } else { None };
        Ok(DisparityStage { engine, check, min_confidence: 0.0, keep_dense: false })
    }

    /// The validity mask's threshold in [0, 1] (refused outside it).
    pub fn with_min_confidence(mut self, c: f32) -> Result<Self> {
        if !(0.0..=1.0).contains(&c) {
            return Err(RuntimeError::Invalid(format!("min_confidence {c} must be in [0, 1]")));
        }
        self.min_confidence = c;
        Ok(self)
    }

    /// Keeps the disparity before the mask in [`Work::dense_disparity`] (when the engine scores its pixels):
    /// for a sink that scores what the mask removed.
    pub fn with_dense_kept(mut self, keep: bool) -> Self {
        self.keep_dense = keep;
        self
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
        let frames_carry_check = self.check.as_ref().is_some_and(|c| c.cfg.confidence);
        if frames_carry_check || self.engine.confidence().is_some() {
            w.confidence = vec![0.0; w.disparity.len()];
        }
        if self.engine.confidence().is_some() {
            w.reason = vec![0; w.disparity.len()];
            if self.keep_dense {
                w.dense_disparity = vec![f32::NAN; w.disparity.len()];
            }
        }
    }

    fn process(&mut self, w: &mut Work) -> Result<()> {
        if w.motion.gated {
            // the motion gate: too blurred to match, so not matched (saves the engine's time during saccades)
            w.disparity.fill(f32::NAN);
            w.dense_disparity.fill(f32::NAN);
            w.confidence.fill(0.0);
            w.reason.fill(reason::NO_ESTIMATE);
            return Ok(());
        }
        let Work { rectified, disparity, confidence, reason, dense_disparity, .. } = w;
        self.engine.compute(&rectified.left, &rectified.right, disparity).map_err(runtime_error)?;
        if let Some((conf, why)) = self.engine.confidence() {
            if dense_disparity.len() == disparity.len() {
                for ((d, &e), &v) in dense_disparity.iter_mut().zip(disparity.iter()).zip(&rectified.valid) {
                    *d = if v == 0 { f32::NAN } else { e };
                }
            }
            own_mask(conf, why, &rectified.valid, self.min_confidence, disparity, confidence, reason)?;
        }
        if let Some(c) = &mut self.check {
            let conf = if c.cfg.confidence { Some(&mut confidence[..]) } else { None };
            let (l, r, valid) = (&rectified.left, &rectified.right, Some(&rectified.valid[..]));
            c.run(self.engine.as_mut(), l, r, valid, disparity, conf, None).map_err(runtime_error)?;
        }
        Ok(())
    }

    fn failure(&self, _e: &RuntimeError) -> &'static str {
        "disparity engine failed"
    }
}

/// The engine's confidence `conf` and reasons `why` into the frame's (0 and `NO_ESTIMATE` where the
/// rectified pixel does not see the raw image), then the validity mask at `min`
/// ([`abvs_disparity::confidence::mask`]).
fn own_mask(
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
    mask_into(conf, why, valid, min, disparity, out_conf, out_why);
    Ok(())
}
