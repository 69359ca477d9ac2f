//! One engine's answer on an image pair of any size, at the pair's resolution: what `abvs disparity`
//! writes and `abvs disparity-eval` scores.
//!
//! The network and the plain SGBM engine run at the model's resolution: inputs are resized to it
//! (INTER_AREA; anisotropic resizes keep rows epipolar) and disparities resampled back (bilinear) and
//! scaled by the width ratio. The fused engine runs SGBM at the input resolution and the network at its
//! own ([`crate::fused`]); census-refine refines the network's answer, with SGBM's checked matches at the
//! network's resolution when the input is larger ([`crate::census`]). The left-right check is
//! [`crate::confidence::LrCheck`], the runtime's.
use std::path::Path;

use opencv::core::Mat;
use opencv::prelude::*;

use crate::census::CensusRefineEngine;
use crate::confidence::{reason, LrCheck};
use crate::engine::{compute, set_opencv_threads, DisparityEngine};
use crate::error::{cv, DisparityError, Result};
use crate::fused::FusedEngine;
use crate::manifest::refine_base;
use crate::onnx::OnnxEngine;
use crate::resample::{nearest_centred, resize_mat, upsample_disparity};
use crate::sgbm::SgbmEngine;
use abvs_runtime_core::params::CheckConfig;

/// One engine's answer at the input resolution.
pub struct Estimate {
    /// The engine's name ([`DisparityEngine::name`]).
    pub engine: String,
    /// Where the network ran (the fused engine's SGBM runs at the input resolution).
    pub model_size: (u32, u32),
    /// Left-view disparity in input pixels, NaN where invalid.
    pub disparity: Vec<f32>,
    /// With the left-right check: confidence in [0, 1] and the invalid reason per pixel.
    pub checked: Option<(Vec<f32>, Vec<u8>)>,
    /// The engine's own confidence and reasons (census-refine's, no second run), of the dense `disparity`.
    pub own: Option<(Vec<f32>, Vec<u8>)>,
}

/// An image read as 8-bit gray (any format OpenCV reads).
pub fn read_gray(path: &Path) -> Result<Mat> {
    let name = path
        .to_str()
        .ok_or_else(|| DisparityError::Format { path: path.to_path_buf(), msg: "path is not UTF-8".into() })?;
    let m = opencv::imgcodecs::imread(name, opencv::imgcodecs::IMREAD_GRAYSCALE).map_err(cv("imread"))?;
    if m.empty() {
        return Err(DisparityError::Format {
            path: path.to_path_buf(),
            msg: "cannot read the image (missing or not an image)".into(),
        });
    }
    Ok(m)
}

/// The left-right check of `engine`'s answer `d` on the pair it just ran on (at its resolution): the
/// failing pixels invalidated, the confidence and the reasons returned.
fn checked(
    engine: &mut dyn DisparityEngine,
    left: &[u8],
    right: &[u8],
    d: &mut [f32],
    max_diff: f32,
) -> Result<(Vec<f32>, Vec<u8>)> {
    let (w, h) = engine.size();
    let mut check = LrCheck::new(CheckConfig { confidence: true, invalidate: true, max_diff })?;
    check.start(w, h);
    let (mut conf, mut why) = (vec![0f32; d.len()], vec![reason::VALID; d.len()]);
    check.run(engine, left, right, None, d, Some(&mut conf), Some(&mut why))?;
    Ok((conf, why))
}

/// Runs engine `kind` ([`crate::factory::ENGINES`]; the network from `model`) on a pair of 8-bit gray
/// images of one size; with `lr_max_diff` the left-right check too.
pub fn estimate(
    l: &Mat,
    r: &Mat,
    kind: &str,
    model: &Path,
    threads: usize,
    lr_max_diff: Option<f32>,
) -> Result<Estimate> {
    let cvm = cv("estimate");
    if l.size().map_err(&cvm)? != r.size().map_err(&cvm)? {
        return Err(DisparityError::Invalid(format!(
            "left {}x{} and right {}x{} differ in size",
            l.cols(),
            l.rows(),
            r.cols(),
            r.rows()
        )));
    }
    set_opencv_threads(threads)?;
    let onnx = match kind {
        "census-refine" => OnnxEngine::load(&refine_base(model)?, threads)?,
        "fused" | "onnx" | "sgbm" => OnnxEngine::load(model, threads)?,
        other => {
            return Err(DisparityError::Invalid(format!(
                "unknown disparity engine `{other}` ({})",
                crate::factory::ENGINES.join(" | ")
            )))
        }
    };
    let (mw, mh) = (onnx.manifest.width, onnx.manifest.height);
    let (iw, ih) = (l.cols() as u32, l.rows() as u32);
    let isize = (iw as usize, ih as usize);
    if kind == "census-refine" || kind == "fused" {
        // both run at the input resolution
        let mut e: Box<dyn DisparityEngine> = if kind == "fused" {
            Box::new(FusedEngine::new(onnx, iw, ih)?)
        } else {
            Box::new(CensusRefineEngine::new(onnx, iw, ih)?)
        };
        let (lb, rb) = (l.data_bytes().map_err(&cvm)?.to_vec(), r.data_bytes().map_err(&cvm)?.to_vec());
        let mut d = compute(e.as_mut(), &lb, &rb)?;
        let own = e.confidence().map(|(c, why)| (c.to_vec(), why.to_vec()));
        let checked = lr_max_diff.map(|m| checked(e.as_mut(), &lb, &rb, &mut d, m)).transpose()?;
        return Ok(Estimate { engine: e.name().to_string(), model_size: (mw, mh), disparity: d, checked, own });
    }
    let max = onnx.manifest.max_disparity;
    let mut engine: Box<dyn DisparityEngine> =
        if kind == "sgbm" { Box::new(SgbmEngine::new(mw, mh, max)?) } else { Box::new(onnx) };
    let (lm, rm) = (resize_mat(l, mw as i32, mh as i32)?, resize_mat(r, mw as i32, mh as i32)?);
    let mut d = compute(engine.as_mut(), &lm, &rm)?;
    let msize = (mw as usize, mh as usize);
    let checked = match lr_max_diff {
        None => None,
        Some(max_diff) => {
            let (conf, why) = checked(engine.as_mut(), &lm, &rm, &mut d, max_diff)?;
            let (mut c, mut w) = (vec![0f32; isize.0 * isize.1], vec![reason::NO_ESTIMATE; isize.0 * isize.1]);
            nearest_centred(&conf, msize, &mut c, isize);
            nearest_centred(&why, msize, &mut w, isize);
            Some((c, w))
        }
    };
    // back to the input resolution, values scaled by the width ratio
    let mut out = vec![f32::NAN; isize.0 * isize.1];
    upsample_disparity(&d, msize, &mut out, isize);
    Ok(Estimate { engine: engine.name().to_string(), model_size: (mw, mh), disparity: out, checked, own: None })
}
