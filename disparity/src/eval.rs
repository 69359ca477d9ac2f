//! Disparity engines scored against a ground-truth map, as typed rows (`abvs disparity-eval` prints, plots
//! and writes them as JSON): EPE over the pixels an engine answers, bad-1/2/3 as % of valid ground-truth
//! pixels (a pixel without an estimate counts as bad), each engine's time (median of repeated runs), and what
//! it publishes. [`eval_native`] scores what `abvs disparity` gives at the input's resolution (the default
//! engine, the runtime's default census-refine, each network, SGBM_3WAY with the ground truth's range) with
//! the left-right check's density and bad-2 against density curves; [`eval_at_model_resolution`] scores each
//! model at its own resolution against SGBM at the same one.
use std::path::{Path, PathBuf};
use std::time::Instant;

use abvs_runtime_core::config::EngineKind;
use abvs_runtime_core::params::DEFAULT_MIN_CONFIDENCE;
use opencv::core::Mat;
use opencv::prelude::*;
use serde::Serialize;

use crate::census::CensusRefineEngine;
use crate::confidence::mask;
use crate::engine::{compute, DisparityEngine};
use crate::error::{cv, DisparityError, Result};
use crate::estimate::estimate;
use crate::fused::FusedEngine;
use crate::manifest::{default_model_for, refine_base};
use crate::onnx::OnnxEngine;
use crate::resample::{resize_mat, upsample_disparity};
use crate::score::{bad2_at, density_at, density_curve, load_gt, mask_curve, published_score, score_disparity};
use crate::sgbm::SgbmEngine;

/// Where the ground truth is and how the engines run.
#[derive(Debug, Clone)]
pub struct EvalSpec {
    /// Ground truth: PFM (pixels) or an 8/16-bit PNG divided by `gt_scale`.
    pub gt: PathBuf,
    /// Divisor of a PNG ground truth's values.
    pub gt_scale: f64,
    /// Model directories or .onnx files to score (the shipped variants when the caller gives none).
    pub models: Vec<PathBuf>,
    /// Timed runs per engine (median reported).
    pub runs: usize,
    /// Threads of the ONNX engine.
    pub threads: usize,
}

/// One engine's scores; the optional parts are those of one mode (absent from the JSON when `None`).
#[derive(Debug, Clone, Serialize)]
pub struct EvalRow {
    /// The engine's name (as `abvs disparity` and `abvs run` report it).
    pub engine: String,
    /// The resolution it was scored at, "WxH".
    pub resolution: String,
    /// Mean |d - gt| over the answered pixels (px).
    pub epe_px: f64,
    /// bad-1 (% of the valid ground-truth pixels).
    pub bad1_pct: f64,
    /// bad-2 (%).
    pub bad2_pct: f64,
    /// bad-3 (%).
    pub bad3_pct: f64,
    /// Answered fraction of the valid ground-truth pixels.
    pub valid_fraction: f64,
    /// Valid ground-truth pixels.
    pub gt_pixels: usize,
    /// Median time of one disparity (ms; resizing and resampling included, model loading not).
    pub ms_median: f64,
    /// What is published (the validity mask at its default where the engine scores its pixels).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub published: Option<Published>,
    /// The engine's own confidence (census-refine, fused).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub own_confidence: Option<OwnConfidence>,
    /// The left-right check's effect (the default engine and network).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lr_check: Option<LrCheckScore>,
    /// The default engine of `abvs disparity`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub default: Option<bool>,
    /// The runtime's default engine.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub runtime_default: Option<bool>,
    /// The network's own resolution ("-" for SGBM).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub network_resolution: Option<String>,
    /// The engine's disparity range (at the model's resolution).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_disparity: Option<f64>,
    /// Ground-truth pixels beyond that range (not scored).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gt_pixels_beyond_max_disparity: Option<usize>,
}

/// Density and bad-2 among the published pixels.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Published {
    /// Fraction of the ground-truth pixels with a published disparity.
    pub density: f64,
    /// bad-2 (%) among them.
    pub bad2_pct_of_valid: f64,
}

/// What an engine's own confidence is worth against SGBM's published pixels.
#[derive(Debug, Clone, Serialize)]
pub struct OwnConfidence {
    /// The validity mask's default threshold.
    pub min_confidence: f32,
    /// bad-2 among the kept at SGBM's density.
    pub bad2_pct_of_valid_at_sgbm_density: Option<f64>,
    /// The largest density whose bad-2 is at most SGBM's.
    pub density_at_sgbm_bad2: f64,
    /// (threshold, density, bad-2 %) at thresholds 0, 0.05, ..., 1.
    pub mask_curve: Vec<[f64; 3]>,
}

/// What the left-right check keeps.
#[derive(Debug, Clone, Serialize)]
pub struct LrCheckScore {
    /// Fraction of the ground-truth pixels kept.
    pub density: f64,
    /// bad-2 (%) over the kept ones.
    pub bad2_pct_of_kept: f64,
    /// Kept by confidence down to 85 % density.
    pub at_85pct_density: Option<AtDensity>,
}

/// A point of a bad-2 against density curve.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct AtDensity {
    /// Density there.
    pub density: f64,
    /// bad-2 (%) over the kept ones.
    pub bad2_pct_of_kept: f64,
    /// Share of the full-density bad-2 pixels that the removed ones took away.
    pub bad2_removed_fraction: f64,
}

/// [`eval_native`]'s answer: the rows (SGBM last) and the bad-2 against density curves to plot.
#[derive(Debug, Clone)]
pub struct NativeEval {
    /// One row per engine, SGBM last.
    pub rows: Vec<EvalRow>,
    /// (label, [(density, bad-2 %)]) per engine with a confidence.
    pub curves: Vec<(String, Vec<(f64, f64)>)>,
    /// SGBM's published (density, bad-2 %): one point, its own checks.
    pub sgbm_published: (f64, f64),
}

fn row(engine: String, resolution: String, d: &[f32], gt: &[f32], max_disp: f64, ms: f64) -> EvalRow {
    let s = score_disparity(d, gt, max_disp);
    EvalRow {
        engine,
        resolution,
        epe_px: s.epe_px,
        bad1_pct: s.bad_pct[0],
        bad2_pct: s.bad_pct[1],
        bad3_pct: s.bad_pct[2],
        valid_fraction: s.valid_fraction,
        gt_pixels: s.gt_pixels,
        ms_median: ms,
        published: None,
        own_confidence: None,
        lr_check: None,
        default: None,
        runtime_default: None,
        network_resolution: None,
        max_disparity: None,
        gt_pixels_beyond_max_disparity: None,
    }
}

/// Median of `runs` timed calls (ms).
pub fn median_ms(runs: usize, mut f: impl FnMut() -> Result<()>) -> Result<f64> {
    let mut t = Vec::with_capacity(runs.max(1));
    for _ in 0..runs.max(1) {
        let s = Instant::now();
        f()?;
        t.push(s.elapsed().as_secs_f64() * 1e3);
    }
    t.sort_by(f64::total_cmp);
    Ok(t[t.len() / 2])
}

/// Each model at its own resolution (the networks' training protocol), then SGBM at the same one.
pub fn eval_at_model_resolution(l: &Mat, r: &Mat, spec: &EvalSpec) -> Result<Vec<EvalRow>> {
    if spec.models.is_empty() {
        return Err(DisparityError::Invalid("no disparity model given and none shipped under models/hitnet/".into()));
    }
    let mut rows = Vec::new();
    for m in &spec.models {
        let onnx = OnnxEngine::load(m, spec.threads)?;
        let (w, h, max) = (onnx.manifest.width, onnx.manifest.height, onnx.manifest.max_disparity);
        let (lv, rv) = (resize_mat(l, w as i32, h as i32)?, resize_mat(r, w as i32, h as i32)?);
        let (_, _, gt) = load_gt(&spec.gt, spec.gt_scale, w, h)?;
        let beyond = gt.iter().filter(|g| g.is_finite() && (**g as f64) >= max).count();
        let engines: Vec<Box<dyn DisparityEngine>> = vec![Box::new(onnx), Box::new(SgbmEngine::new(w, h, max)?)];
        for mut e in engines {
            let d = compute(e.as_mut(), &lv, &rv)?;
            let mut buf = d.clone();
            let ms = median_ms(spec.runs, || e.compute(&lv, &rv, &mut buf))?;
            let mut s = row(e.name().to_string(), format!("{w}x{h}"), &d, &gt, max, ms);
            s.max_disparity = Some(max);
            s.gt_pixels_beyond_max_disparity = Some(beyond);
            rows.push(s);
        }
    }
    Ok(rows)
}

/// The engine `kind` on the pair, timed: resizing and resampling included, model loading not.
fn time_engine(kind: EngineKind, model: &Path, l: &Mat, r: &Mat, spec: &EvalSpec) -> Result<f64> {
    let cvm = cv("disparity-eval");
    let (iw, ih) = (l.cols() as u32, l.rows() as u32);
    let (lb, rb) = (l.data_bytes().map_err(&cvm)?.to_vec(), r.data_bytes().map_err(&cvm)?.to_vec());
    let net = if kind == EngineKind::CensusRefine { refine_base(model)? } else { model.to_path_buf() };
    let onnx = OnnxEngine::load(&net, spec.threads)?;
    let (mw, mh) = onnx.size();
    let mut out = vec![0f32; (iw * ih) as usize];
    if kind == EngineKind::Fused {
        let mut e = FusedEngine::new(onnx, iw, ih)?;
        median_ms(spec.runs, || e.compute(&lb, &rb, &mut out))
    } else if kind == EngineKind::CensusRefine {
        let mut e = CensusRefineEngine::new(onnx, iw, ih)?;
        median_ms(spec.runs, || e.compute(&lb, &rb, &mut out))
    } else {
        let mut e = onnx;
        median_ms(spec.runs, || {
            let (lm, rm) = (resize_mat(l, mw as i32, mh as i32)?, resize_mat(r, mw as i32, mh as i32)?);
            let d = compute(&mut e, &lm, &rm)?;
            upsample_disparity(&d, (mw as usize, mh as usize), &mut out, (iw as usize, ih as usize));
            Ok(())
        })
    }
}

/// What the left-right check keeps of the engine's answer, and its bad-2 against density by confidence.
fn lr_check(
    l: &Mat,
    r: &Mat,
    kind: EngineKind,
    model: &Path,
    threads: usize,
    gt: &[f32],
    full_bad: f64,
) -> Result<(LrCheckScore, Vec<(f64, f64)>)> {
    let max = f64::INFINITY;
    let chk = estimate(l, r, kind.as_str(), model, threads, Some(1.0))?;
    let (conf, _) = chk.checked.as_ref().ok_or_else(|| DisparityError::Invalid("left-right check".into()))?;
    let kept = score_disparity(&chk.disparity, gt, max);
    let curve = density_curve(&chk.disparity, conf, gt, max);
    let at = |density: f64| curve.iter().rev().find(|(dn, _)| *dn <= density).map(|(dn, b)| (*dn, *b));
    // bad-2 counts unanswered pixels as bad: over the kept ones it is (bad - dropped) / kept
    let v = kept.valid_fraction;
    let score = LrCheckScore {
        density: v,
        bad2_pct_of_kept: (kept.bad_pct[1] - 100.0 * (1.0 - v)) / v.max(1e-9),
        at_85pct_density: at(0.85).map(|(dn, b)| AtDensity {
            density: dn,
            bad2_pct_of_kept: b,
            // share of the full-density bad-2 pixels that the 15 % removed took away
            bad2_removed_fraction: 1.0 - b * dn / full_bad,
        }),
    };
    Ok((score, curve))
}

/// The engines at the input's resolution (what `abvs disparity` gives): the default engine (fused), the
/// runtime's default (census-refine), the default network alone, every other network alone and refined, and
/// SGBM_3WAY over the ground truth's range (last).
pub fn eval_native(l: &Mat, r: &Mat, spec: &EvalSpec) -> Result<NativeEval> {
    let cvm = cv("disparity-eval");
    let (iw, ih) = (l.cols() as u32, l.rows() as u32);
    let (_, _, gt) = load_gt(&spec.gt, spec.gt_scale, iw, ih)?;
    let gt_max = gt.iter().filter(|g| g.is_finite()).fold(0f32, |m, g| m.max(*g)) as f64;
    if gt_max <= 0.0 {
        return Err(DisparityError::Format { path: spec.gt.clone(), msg: "no known ground-truth disparity".into() });
    }
    // nothing is beyond the range here: SGBM searches the ground truth's whole range
    let max = f64::INFINITY;
    let (lb, rb) = (l.data_bytes().map_err(&cvm)?.to_vec(), r.data_bytes().map_err(&cvm)?.to_vec());
    let mut rows = Vec::new();
    let mut curves = Vec::new();
    // SGBM as users run it: SGBM_3WAY at the input resolution, the ground truth's range (first: its density
    // is where the others' curves are read)
    let mut sgbm = SgbmEngine::new(iw, ih, gt_max + 1.0)?;
    let sgbm_d = compute(&mut sgbm, &lb, &rb)?;
    let (sgbm_density, sgbm_bad) = published_score(&sgbm_d, &gt, max);
    let default_model = default_model_for(iw, ih);
    let mut nets = spec.models.clone();
    nets.retain(|m| m != &default_model);
    let mut cases = vec![
        (EngineKind::Fused, default_model.clone(), true),
        (EngineKind::CensusRefine, default_model.clone(), false),
        (EngineKind::Onnx, default_model, true),
    ];
    // every other network alone and refined, so a cheaper base for census-refine is measured too
    cases.extend(
        nets.into_iter().flat_map(|m| [(EngineKind::CensusRefine, m.clone(), false), (EngineKind::Onnx, m, false)]),
    );
    for (kind, model, default) in cases {
        let est = estimate(l, r, kind.as_str(), &model, spec.threads, None)?;
        let ms = time_engine(kind, &model, l, r, spec)?;
        let mut s = row(est.engine.clone(), format!("{iw}x{ih}"), &est.disparity, &gt, max, ms);
        // what is published: the validity mask at its default where the engine scores its pixels
        let mut published = est.disparity.clone();
        if let Some((conf, why)) = &est.own {
            let min = DEFAULT_MIN_CONFIDENCE;
            mask(conf, min, &mut published, &mut why.clone());
            let curve = density_curve(&est.disparity, conf, &gt, max);
            let ts: Vec<f32> = (0..=20).map(|i| i as f32 * 0.05).collect();
            s.own_confidence = Some(OwnConfidence {
                min_confidence: min,
                bad2_pct_of_valid_at_sgbm_density: bad2_at(&curve, sgbm_density),
                density_at_sgbm_bad2: density_at(&curve, sgbm_bad),
                mask_curve: mask_curve(&est.disparity, conf, &gt, max, &ts),
            });
            curves.push((format!("{} (own confidence)", est.engine), curve));
        }
        let (density, bad2_pct_of_valid) = published_score(&published, &gt, max);
        s.published = Some(Published { density, bad2_pct_of_valid });
        if default {
            let (chk, curve) = lr_check(l, r, kind, &model, spec.threads, &gt, s.bad2_pct)?;
            s.lr_check = Some(chk);
            curves.push((est.engine.clone(), curve));
        }
        s.default = Some(default && kind == EngineKind::Fused);
        s.runtime_default = Some(kind == EngineKind::CensusRefine);
        s.network_resolution = Some(format!("{}x{}", est.model_size.0, est.model_size.1));
        rows.push(s);
    }
    let mut buf = sgbm_d.clone();
    let ms = median_ms(spec.runs, || sgbm.compute(&lb, &rb, &mut buf))?;
    let name = format!("sgbm (range {})", sgbm.max_disparity());
    let mut s = row(name, format!("{iw}x{ih}"), &sgbm_d, &gt, max, ms);
    s.published = Some(Published { density: sgbm_density, bad2_pct_of_valid: sgbm_bad });
    s.default = Some(false);
    s.runtime_default = Some(false);
    s.network_resolution = Some("-".into());
    rows.push(s);
    Ok(NativeEval { rows, curves, sgbm_published: (sgbm_density, sgbm_bad) })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_row_keeps_only_its_modes_fields_in_json() {
        let gt = [10.0, 10.0, 10.0, f32::NAN];
        let d = [10.5, 13.0, f32::INFINITY, 4.0];
        let mut r = row("sgbm".into(), "4x1".into(), &d, &gt, 100.0, 1.5);
        assert_eq!((r.gt_pixels, r.valid_fraction), (3, 2.0 / 3.0));
        assert!((r.bad2_pct - 200.0 / 3.0).abs() < 1e-9 && (r.epe_px - 1.75).abs() < 1e-12);
        r.published = Some(Published { density: 0.5, bad2_pct_of_valid: 1.0 });
        let j = serde_json::to_value(&r).unwrap();
        assert_eq!(j["published"]["density"], 0.5);
        for absent in ["own_confidence", "lr_check", "default", "max_disparity"] {
            assert!(j.get(absent).is_none(), "{absent} in {j}");
        }
    }

    #[test]
    fn the_median_is_of_the_given_runs() {
        let mut n = 0;
        let ms = median_ms(5, || {
            n += 1;
            Ok(())
        })
        .unwrap();
        assert_eq!(n, 5);
        assert!(ms >= 0.0);
        assert!(median_ms(3, || Err(DisparityError::Invalid("x".into()))).is_err());
    }
}
