//! `abvs disparity`: the left-view disparity of a rectified image pair, by any engine of `abvs run` under
//! the same names (`abvs_runtime_core::config::EngineKind`; default: fused), with an optional left-right check,
//! confidence and invalid reasons.
//!
//! The network and the plain SGBM engine run at the model's resolution: inputs are resized to it
//! (INTER_AREA; anisotropic resizes keep rows epipolar) and disparities resampled back (bilinear) and
//! scaled by the width ratio. The fused engine runs SGBM at the input resolution and the network at its
//! own (`abvs_runtime::tasks::disparity_fused`); census-refine refines the network's answer, with SGBM's
//! checked matches at the network's resolution when the input is larger
//! (`abvs_runtime::tasks::disparity_census`). The output is PFM at the input resolution, invalid = inf.
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use abvs_runtime::tasks::confidence::{
    self,
    reason::{NO_ESTIMATE, VALID},
};
use abvs_runtime::tasks::disparity::{self, DisparityEngine};
use abvs_runtime::tasks::disparity_census::CensusRefineEngine;
use abvs_runtime::tasks::disparity_fused::{upsample_disparity, FusedEngine, Source};
use abvs_runtime_core::config::EngineKind;
use anyhow::{bail, Context};
use clap::Args;
use opencv::core::{Mat, Size};
use opencv::prelude::*;
use opencv::{imgcodecs, imgproc};

use crate::pfm::write_pfm;

#[derive(Args)]
pub struct DisparityArgs {
    /// Left rectified image (PNG or any format OpenCV reads).
    #[arg(long)]
    left: PathBuf,
    /// Right rectified image, the same size as the left.
    #[arg(long)]
    right: PathBuf,
    /// Output PFM (left-view disparity in pixels at the input resolution, invalid = inf).
    #[arg(long)]
    out: PathBuf,
    /// Model directory or .onnx (default: the shipped model of the largest resolution at most 1.5x the
    /// input's on each axis: hitnet-m (640x480) for inputs from 427x320 up, else hitnet-s).
    #[arg(long)]
    model: Option<PathBuf>,
    /// fused: SGBM where its own checks accept a match, the network elsewhere (the best on real images);
    /// census-refine: the network, SGBM's checked matches at its resolution in its place, refined by a census
    /// search within 3 px (the runtime's default; output at the input resolution); onnx: the network alone;
    /// sgbm: SGBM_3WAY alone (both at the model's resolution).
    #[arg(long, value_enum, default_value_t = EngineKind::Fused)]
    engine: EngineKind,
    /// Threads of the ONNX engine (1 to 256).
    #[arg(long, default_value_t = 2, value_parser = crate::args::count(1usize, 256))]
    threads: usize,
    /// Left-right consistency check: the right view's disparity is computed too (the pair mirrored and
    /// swapped) and a left pixel whose match disagrees by more than --lr-max-diff (px at the engine's
    /// resolution) or falls outside the right image is invalid.
    #[arg(long)]
    lr_check: bool,
    /// Largest left-right disagreement of a valid pixel (px, in (0, 1000]).
    #[arg(long, default_value_t = 1.0, value_parser = crate::args::positive_up_to_f32(1000.0))]
    lr_max_diff: f32,
    /// Per-pixel confidence in [0, 1] as PFM at the input resolution (implies the left-right check), 0 where
    /// invalid: exp(-|d_left - d_right|) of the left-right check; with the fused engine
    /// 0.5 (1 + exp(-|d_sgbm - d_network| / 2 px)) for SGBM's matches and 0.5 exp(-|d_left - d_right|) for
    /// the network's.
    #[arg(long)]
    confidence: Option<PathBuf>,
    /// Why each pixel is invalid, as an 8-bit PNG at the input resolution: 0 valid, 1 no estimate from the
    /// engine (e.g. beyond its disparity range), 2 its match falls outside the right image, 3 left-right
    /// check failed (occlusion or mismatch). Implies the left-right check.
    #[arg(long)]
    invalid_reason: Option<PathBuf>,
    /// census-refine's validity mask: pixels whose confidence (the engine's own, computed as it matches:
    /// `--confidence` writes it without a left-right check) is below C, in [0, 1], are invalid (reason 4 low
    /// texture, 5 ambiguous, 6 out of the search's range, 7 occluded or a depth edge); 0 keeps every pixel.
    /// Other engines ignore it.
    #[arg(long, value_name = "C", default_value_t = abvs_runtime_core::params::DEFAULT_MIN_CONFIDENCE,
          value_parser = crate::args::finite_in_f32(0.0, 1.0))]
    min_confidence: f32,
}

/// The fused engine's confidence scale for network pixels: below every accepted SGBM match, which is right
/// to a fraction of a pixel where the network is not.
const NETWORK_CONFIDENCE: f32 = 0.5;

/// Scale (px) of the fused engine's agreement between SGBM and the network: at the bad-2 threshold the two
/// agree to exp(-1).
const AGREEMENT_PX: f32 = 2.0;

/// The left-right check at the engine's resolution (`abvs_runtime::tasks::confidence`, the runtime's own):
/// per pixel, the reason code and the confidence.
fn lr_check(dl: &[f32], dr: &[f32], w: usize, max_diff: f32) -> (Vec<u8>, Vec<f32>) {
    let (mut d, mut conf, mut why) = (dl.to_vec(), vec![0f32; dl.len()], vec![VALID; dl.len()]);
    confidence::lr_check_with_reasons(&mut d, dr, w, max_diff, false, &mut conf, Some(&mut why));
    (why, conf)
}

/// Each row of a `w`-wide image reversed (the mirror that turns a right view into a left one).
fn mirror<T: Copy + Default>(img: &[T], w: usize) -> Vec<T> {
    let mut out = vec![T::default(); img.len()];
    confidence::mirror_rows(img, w, &mut out);
    out
}

/// Nearest-neighbour resample of a model-resolution map to the input resolution.
fn to_input<T: Copy>(m: &[T], (mw, mh): (usize, usize), (iw, ih): (usize, usize), fill: T) -> Vec<T> {
    let mut out = vec![fill; iw * ih];
    for y in 0..ih {
        let yy = (((y as f32 + 0.5) * mh as f32 / ih as f32) as usize).min(mh - 1);
        for x in 0..iw {
            let xx = (((x as f32 + 0.5) * mw as f32 / iw as f32) as usize).min(mw - 1);
            out[y * iw + x] = m[yy * mw + xx];
        }
    }
    out
}

pub fn gray(path: &Path) -> anyhow::Result<Mat> {
    let m = imgcodecs::imread(path.to_str().context("path is not UTF-8")?, imgcodecs::IMREAD_GRAYSCALE)?;
    if m.empty() {
        bail!("{}: cannot read the image (missing or not an image)", path.display());
    }
    Ok(m)
}

pub fn resize_to(m: &Mat, w: i32, h: i32) -> anyhow::Result<Vec<u8>> {
    let mut r = Mat::default();
    if m.cols() == w && m.rows() == h {
        r = m.try_clone()?;
    } else {
        imgproc::resize(m, &mut r, Size::new(w, h), 0.0, 0.0, imgproc::INTER_AREA)?;
    }
    Ok(r.data_bytes()?.to_vec())
}

pub fn default_models() -> Vec<PathBuf> {
    ["hitnet-s", "hitnet-m"]
        .iter()
        .map(|v| abvs_runtime::shipped::shipped(&format!("models/hitnet/{v}")))
        .filter(|p| p.join("manifest.json").exists())
        .collect()
}

/// The shipped model for an input of `w` x `h`: the largest resolution at most 1.5x the input's on each
/// axis (more detail and a wider disparity range, without inventing much by upsampling: 450x375 and up get
/// hitnet-m, a 320x240 input hitnet-s); the smallest when none qualifies.
pub fn default_model_for(w: u32, h: u32) -> PathBuf {
    let size = |p: &PathBuf| -> Option<(u32, u32)> {
        let text = std::fs::read_to_string(p.join("manifest.json")).ok()?;
        let m: disparity::DisparityManifest = serde_json::from_str(&text).ok()?;
        Some((m.width, m.height))
    };
    let mut shipped: Vec<(PathBuf, (u32, u32))> =
        default_models().into_iter().filter_map(|p| size(&p).map(|s| (p, s))).collect();
    shipped.sort_by_key(|(_, (mw, mh))| mw * mh);
    let fits = shipped.iter().rev().find(|(_, (mw, mh))| 2 * *mw <= 3 * w && 2 * *mh <= 3 * h);
    match fits.or(shipped.first()) {
        Some((p, _)) => p.clone(),
        // none readable: the error names the expected path when it is loaded
        None => abvs_runtime::shipped::shipped("models/hitnet/hitnet-s"),
    }
}

/// Runs an engine on a pair already at its resolution.
pub fn compute(e: &mut dyn DisparityEngine, l: &[u8], r: &[u8]) -> anyhow::Result<Vec<f32>> {
    let (w, h) = e.size();
    let mut d = vec![f32::NAN; (w * h) as usize];
    e.compute(l, r, &mut d)?;
    Ok(d)
}

/// One engine's answer at the input resolution.
pub struct Estimate {
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

/// The right view's disparity of a pair at an engine's resolution: the mirrored right image is a left view
/// of the mirrored left one.
fn right_view(e: &mut dyn DisparityEngine, l: &[u8], r: &[u8]) -> anyhow::Result<Vec<f32>> {
    let w = e.size().0 as usize;
    Ok(mirror(&compute(e, &mirror(r, w), &mirror(l, w))?, w))
}

/// Runs engine `kind` (the network from `model`) on a pair; with `lr_max_diff` the left-right check too.
pub fn estimate(
    l: &Mat,
    r: &Mat,
    kind: EngineKind,
    model: &Path,
    threads: usize,
    lr_max_diff: Option<f32>,
) -> anyhow::Result<Estimate> {
    if l.size()? != r.size()? {
        bail!("left {}x{} and right {}x{} differ in size", l.cols(), l.rows(), r.cols(), r.rows());
    }
    disparity::set_opencv_threads(threads)?;
    let onnx = if kind == EngineKind::CensusRefine {
        disparity::OnnxEngine::load(&disparity::refine_base(model)?, threads)?
    } else {
        disparity::OnnxEngine::load(model, threads)?
    };
    let (mw, mh) = (onnx.manifest.width, onnx.manifest.height);
    let (iw, ih) = (l.cols() as u32, l.rows() as u32);
    let isize = (iw as usize, ih as usize);
    if kind == EngineKind::CensusRefine {
        let mut e = CensusRefineEngine::new(onnx, iw, ih)?;
        let (lb, rb) = (l.data_bytes()?.to_vec(), r.data_bytes()?.to_vec());
        let mut d = compute(&mut e, &lb, &rb)?;
        let own = e.confidence().map(|(c, why)| (c.to_vec(), why.to_vec()));
        let checked = match lr_max_diff {
            None => None,
            Some(max_diff) => {
                let dr = right_view(&mut e, &lb, &rb)?;
                let (reason, conf) = lr_check(&d, &dr, iw as usize, max_diff);
                for (v, &why) in d.iter_mut().zip(&reason) {
                    if why != VALID {
                        *v = f32::NAN;
                    }
                }
                Some((conf, reason))
            }
        };
        return Ok(Estimate { engine: e.name().to_string(), model_size: (mw, mh), disparity: d, checked, own });
    }
    if kind == EngineKind::Fused {
        let mut e = FusedEngine::new(onnx, iw, ih)?;
        let (lb, rb) = (l.data_bytes()?.to_vec(), r.data_bytes()?.to_vec());
        let mut d = compute(&mut e, &lb, &rb)?;
        let checked = match lr_max_diff {
            None => None,
            Some(max_diff) => {
                // SGBM's matches passed its own left-right check; the network's get one at its resolution
                let (net, nl, nr, nd) = e.network();
                let nd = nd.to_vec();
                let (nl, nr) = (nl.to_vec(), nr.to_vec());
                let dr = right_view(net, &nl, &nr)?;
                let (why, conf) = lr_check(&nd, &dr, mw as usize, max_diff);
                let (why, conf) = (
                    to_input(&why, (mw as usize, mh as usize), isize, NO_ESTIMATE),
                    to_input(&conf, (mw as usize, mh as usize), isize, 0.0),
                );
                let mut c = vec![0f32; d.len()];
                let mut reason = vec![NO_ESTIMATE; d.len()];
                let net_d = e.network_disparity();
                for (i, s) in e.sources().iter().enumerate() {
                    match s {
                        // two independent matchers that agree are surer than one
                        Source::Sgbm => {
                            let agree = (-(d[i] - net_d[i]).abs() / AGREEMENT_PX).exp();
                            (c[i], reason[i]) =
                                (NETWORK_CONFIDENCE * (1.0 + if agree.is_finite() { agree } else { 0.0 }), VALID)
                        }
                        // a network pixel is never as sure as an accepted SGBM match
                        Source::Network if why[i] == VALID => (c[i], reason[i]) = (NETWORK_CONFIDENCE * conf[i], VALID),
                        Source::Network => {
                            reason[i] = why[i];
                            d[i] = f32::NAN;
                        }
                        Source::None => {}
                    }
                }
                Some((c, reason))
            }
        };
        return Ok(Estimate { engine: e.name().to_string(), model_size: (mw, mh), disparity: d, checked, own: None });
    }
    let max = onnx.manifest.max_disparity;
    let mut engine: Box<dyn DisparityEngine> = match kind {
        EngineKind::Sgbm => Box::new(disparity::SgbmEngine::new(mw, mh, max)?),
        _ => Box::new(onnx),
    };
    let (lm, rm) = (resize_to(l, mw as i32, mh as i32)?, resize_to(r, mw as i32, mh as i32)?);
    let mut d = compute(engine.as_mut(), &lm, &rm)?;
    let msize = (mw as usize, mh as usize);
    let checked = match lr_max_diff {
        None => None,
        Some(max_diff) => {
            let dr = right_view(engine.as_mut(), &lm, &rm)?;
            let (reason, conf) = lr_check(&d, &dr, mw as usize, max_diff);
            for (v, &why) in d.iter_mut().zip(&reason) {
                if why != VALID {
                    *v = f32::NAN;
                }
            }
            Some((to_input(&conf, msize, isize, 0.0), to_input(&reason, msize, isize, NO_ESTIMATE)))
        }
    };
    // back to the input resolution, values scaled by the width ratio
    let mut out = vec![f32::NAN; isize.0 * isize.1];
    upsample_disparity(&d, msize, &mut out, isize);
    Ok(Estimate { engine: engine.name().to_string(), model_size: (mw, mh), disparity: out, checked, own: None })
}

pub fn run_disparity(a: DisparityArgs) -> anyhow::Result<ExitCode> {
    let (l, r) = (gray(&a.left)?, gray(&a.right)?);
    let model = a.model.clone().unwrap_or_else(|| default_model_for(l.cols() as u32, l.rows() as u32));
    // census-refine scores its own pixels: its confidence and reasons need no left-right check
    let own = a.engine.scores_pixels() && !a.lr_check;
    let check = a.lr_check || (!own && (a.confidence.is_some() || a.invalid_reason.is_some()));
    let mut est = estimate(&l, &r, a.engine, &model, a.threads, check.then_some(a.lr_max_diff))?;
    let (iw, ih) = (l.cols() as usize, l.rows() as usize);
    if let (true, Some((conf, why))) = (own, &mut est.own) {
        abvs_runtime::tasks::census_confidence::mask(conf, a.min_confidence, &mut est.disparity, why);
        est.checked = est.own.take();
    }
    if let Some((conf, reason)) = &est.checked {
        if let Some(p) = &a.confidence {
            write_pfm(p, iw, ih, conf)?;
        }
        if let Some(p) = &a.invalid_reason {
            image::GrayImage::from_raw(iw as u32, ih as u32, reason.clone())
                .context("reason map size")?
                .save(p)
                .with_context(|| format!("writing {}", p.display()))?;
        }
    }
    write_pfm(&a.out, iw, ih, &est.disparity)?;
    let valid = est.disparity.iter().filter(|v| v.is_finite()).count();
    let (mw, mh) = est.model_size;
    eprintln!(
        "wrote {} ({iw}x{ih}, engine {}, network at {mw}x{mh}, {:.1}% valid)",
        a.out.display(),
        est.engine,
        100.0 * valid as f64 / est.disparity.len() as f64
    );
    Ok(ExitCode::SUCCESS)
}
