//! Builds any engine by name: the top of the crate's engines (it knows them all, none knows it).
use std::path::Path;

use crate::census::CensusRefineEngine;
use crate::engine::{set_opencv_threads, DisparityEngine};
use crate::error::{DisparityError, Result};
use crate::fused::FusedEngine;
use crate::manifest::refine_base;
use crate::onnx::OnnxEngine;
use crate::sgbm::SgbmEngine;

/// The engines [`engine`] builds, by name (the runtime's `EngineKind::as_str`).
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
    let needs = || DisparityError::Invalid(format!("engine {kind} needs a model"));
    let load = || {
        let p = model.ok_or_else(needs)?;
        OnnxEngine::load(p, threads).map(|e| (p, e))
    };
    set_opencv_threads(threads)?;
    match kind {
        "sgbm" => Ok(Box::new(SgbmEngine::new(size.0, size.1, max_disparity)?)),
        "onnx" => {
            let (p, e) = load()?;
            if e.size() != size {
                return Err(DisparityError::Model {
                    path: p.to_path_buf(),
                    msg: format!("model runs at {}x{}, the pipeline at {}x{}", e.size().0, e.size().1, size.0, size.1),
                });
            }
            Ok(Box::new(e))
        }
        // these two resize the network's input, so any model size goes
        "census-refine" => {
            let net = OnnxEngine::load(&refine_base(model.ok_or_else(needs)?)?, threads)?;
            Ok(Box::new(CensusRefineEngine::new(net, size.0, size.1)?))
        }
        "fused" => Ok(Box::new(FusedEngine::new(load()?.1, size.0, size.1)?)),
        other => Err(DisparityError::Invalid(format!("unknown disparity engine `{other}` ({})", ENGINES.join(" | ")))),
    }
}
