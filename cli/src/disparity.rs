//! `abvs disparity`: the left-view disparity of a rectified image pair, by any engine of `abvs run` under
//! the same names (`abvs_runtime_core::config::EngineKind`; default: fused), with an optional left-right check,
//! confidence and invalid reasons: flags around `abvs_disparity::estimate` (how each engine runs at the
//! input's resolution). The output is PFM at the input resolution, invalid = inf.
use std::path::PathBuf;
use std::process::ExitCode;

use abvs_disparity::confidence::mask;
use abvs_disparity::estimate::{estimate, read_gray};
use abvs_disparity::manifest::default_model_for;
use abvs_disparity::pfm::write_pfm;
use abvs_runtime_core::config::EngineKind;
use abvs_runtime_core::params::DEFAULT_MIN_CONFIDENCE;
use abvs_runtime_core::params::MAX_DIFF_LIMIT;
use anyhow::Context;
use clap::Args;
use opencv::prelude::*;

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
    /// Largest left-right disagreement of a valid pixel (px, in (0, 50], the runtime's `lr_max_diff` range).
    #[arg(long, default_value_t = 1.0, value_parser = crate::args::positive_up_to_f32(MAX_DIFF_LIMIT))]
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
    #[arg(long, value_name = "C", default_value_t = DEFAULT_MIN_CONFIDENCE,
          value_parser = crate::args::finite_in_f32(0.0, 1.0))]
    min_confidence: f32,
}

pub fn run_disparity(a: DisparityArgs) -> anyhow::Result<ExitCode> {
    let (l, r) = (read_gray(&a.left)?, read_gray(&a.right)?);
    let model = a.model.clone().unwrap_or_else(|| default_model_for(l.cols() as u32, l.rows() as u32));
    // census-refine scores its own pixels: its confidence and reasons need no left-right check
    let own = a.engine.scores_pixels() && !a.lr_check;
    let check = a.lr_check || (!own && (a.confidence.is_some() || a.invalid_reason.is_some()));
    let mut est = estimate(&l, &r, a.engine.as_str(), &model, a.threads, check.then_some(a.lr_max_diff))?;
    let (iw, ih) = (l.cols() as usize, l.rows() as usize);
    if let (true, Some((conf, why))) = (own, &mut est.own) {
        mask(conf, a.min_confidence, &mut est.disparity, why);
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
