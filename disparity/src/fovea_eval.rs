//! The fovea on a static rectified pair with ground truth (`abvs disparity-eval --fovea WxH`): the runtime's
//! main map against the runtime's fovea ([`crate::fovea`], the same code) over a central window.
//!
//! The main map is the runtime's default engine (census-refine) at [`MAIN_WIDTH`] px wide (the pair resized
//! with its aspect kept), its validity mask at the default `min_confidence`, upsampled to the pair's size
//! (bilinear, values times the width ratio). The fovea matches the central window at the pair's own scale
//! with the runtime's widest search ([`FoveaConfig`]'s `max_range_px`) around that main map and refines it
//! against the main map's nearest pixel, as the runtime does. A static pair has no depth range: the limits
//! are the disparities 0 to the image's width.
use opencv::core::Mat;
use opencv::prelude::*;
use serde::Serialize;

use crate::confidence::mask;
use crate::error::{cv, DisparityError, Result};
use crate::estimate::estimate;
use crate::fovea::{main_histogram, search_range, static_window, FoveaMatcher, MainAt, RefineCounts, HIST_BINS_PER_PX};
use crate::manifest::default_model_for;
use crate::resample::{resize_mat, upsample_disparity};
use abvs_runtime_core::params::{FoveaConfig, DEFAULT_MIN_CONFIDENCE};

/// Width of the main map (px): the runtime's processing width.
pub const MAIN_WIDTH: u32 = 640;

/// One map's score over the window.
#[derive(Clone, Debug, Serialize)]
pub struct MapScore {
    /// Answered pixels / pixels with ground truth.
    pub density: f64,
    /// Mean |d - gt| over the pixels both maps answer (px at the pair's scale).
    pub epe_px: f64,
    /// % of those pixels with |d - gt| > 1 px.
    pub bad1_pct: f64,
}

/// The main map and the fovea over one window of a pair.
#[derive(Clone, Debug, Serialize)]
pub struct FoveaEval {
    /// The pair's size (px).
    pub size: [u32; 2],
    /// The window: x0, y0, width, height (px).
    pub window: [u32; 4],
    /// The main map's resolution (px).
    pub main_resolution: [u32; 2],
    /// The main map's engine.
    pub engine: String,
    /// Its validity mask's threshold.
    pub min_confidence: f32,
    /// The fovea's search `[start, end)` (px at the pair's scale).
    pub search_px: [f64; 2],
    /// Whether the search came from the main map (else around the main map's median over the image).
    pub from_main: bool,
    /// How often the refinement rule acted (window pixels).
    pub filled_from_main: u64,
    /// See [`RefineCounts::overruled`].
    pub overruled_by_main: u64,
    /// See [`RefineCounts::masked`].
    pub masked_by_main: u64,
    /// Window pixels with ground truth.
    pub gt_pixels: u64,
    /// Of those, the pixels both maps answer (where EPE and bad-1 are taken).
    pub common_pixels: u64,
    /// The main map upsampled.
    pub main: MapScore,
    /// The fovea.
    pub fovea: MapScore,
    /// fovea EPE / main EPE.
    pub epe_ratio: f64,
}

/// The main map and the fovea over the central `win` window of the rectified pair `l`, `r` (8-bit gray, one
/// size), scored against `gt` (the pair's size, NaN = unknown); OpenCV and the network on `threads`.
pub fn eval_fovea(l: &Mat, r: &Mat, gt: &[f32], win: (u32, u32), threads: usize) -> Result<FoveaEval> {
    let cvm = cv("fovea eval");
    let (iw, ih) = (l.cols() as u32, l.rows() as u32);
    let (w, h) = win;
    if w > iw || h > ih || gt.len() != (iw * ih) as usize {
        return Err(DisparityError::Invalid(format!(
            "fovea window {w}x{h} does not fit the {iw}x{ih} pair (ground truth of {} px)",
            gt.len()
        )));
    }
    // the main map: the runtime's default engine at MAIN_WIDTH, masked, upsampled
    let (mw, mh) = (MAIN_WIDTH.min(iw), ((ih as f64 * MAIN_WIDTH.min(iw) as f64 / iw as f64).round() as u32).max(16));
    let to = |m: &Mat| -> Result<Mat> {
        let v = resize_mat(m, mw as i32, mh as i32)?;
        Mat::new_rows_cols_with_data(mh as i32, mw as i32, &v).map_err(&cvm)?.try_clone().map_err(&cvm)
    };
    let (lm, rm) = (to(l)?, to(r)?);
    let est = estimate(&lm, &rm, "census-refine", &default_model_for(mw, mh), threads, None)?;
    let mut main = est.disparity;
    let (conf, why) = est.own.ok_or_else(|| DisparityError::Invalid("census-refine without its confidence".into()))?;
    mask(&conf, DEFAULT_MIN_CONFIDENCE, &mut main, &mut why.clone());
    let mut up = vec![f32::NAN; (iw * ih) as usize];
    upsample_disparity(&main, (mw as usize, mh as usize), &mut up, (iw as usize, ih as usize));
    // the fovea: the central window at the pair's scale
    let scale = iw as f64 / mw as f64;
    let (x0, y0) = ((iw - w) / 2, (ih - h) / 2);
    let to_main = |x: f64, n: u32| (((x + 0.5) / scale - 0.5).round().clamp(0.0, n as f64 - 1.0)) as usize;
    let (u0, u1) = (to_main(x0 as f64, mw), to_main((x0 + w - 1) as f64, mw));
    let (v0, v1) = (to_main(y0 as f64, mh), to_main((y0 + h - 1) as f64, mh));
    let mut hist = vec![0u32; (mw as f64 * HIST_BINS_PER_PX) as usize + 1];
    let n = main_histogram(&main, mw as usize, (u0, u1), (v0, v1), &mut hist);
    let max_range = FoveaConfig::default().max_range_px;
    // fallback centre: the main map's median over the whole image
    let mut all: Vec<f32> = main.iter().copied().filter(|d| *d > 0.0).collect();
    all.sort_by(f32::total_cmp);
    let d_fix = all.get(all.len() / 2).map_or(max_range as f64 / 2.0, |d| *d as f64 * scale);
    let lim = [iw as f64, 0.0];
    let window_px = (w as f64 / scale) * (h as f64 / scale);
    let (start, range, from_main) = search_range(&hist, n, window_px, scale, d_fix, max_range, lim);
    let (lb, rb) = (l.data_bytes().map_err(&cvm)?, r.data_bytes().map_err(&cvm)?);
    let (le, re, valid) = static_window(
        lb,
        rb,
        (iw as usize, ih as usize),
        (x0 as i64, y0 as i64),
        (w as usize, h as usize),
        max_range as usize,
        start as i64,
    );
    // the main map at the nearest main pixel, scaled (as the runtime samples it)
    let mut main_at = vec![MainAt::Outside; (w * h) as usize];
    for v in 0..h {
        let vm = to_main((y0 + v) as f64, mh);
        for u in 0..w {
            let d = main[vm * mw as usize + to_main((x0 + u) as f64, mw)];
            main_at[(v * w + u) as usize] =
                if d > 0.0 { MainAt::Disparity((d as f64 * scale) as f32) } else { MainAt::Masked };
        }
    }
    let mut matcher = FoveaMatcher::new(w, h, max_range)?;
    let mut fovea = vec![f32::NAN; (w * h) as usize];
    let RefineCounts { filled, overruled, masked } =
        matcher.fovea(&le, &re, (start, range), &valid, &main_at, scale, lim, &mut fovea)?;
    // both over the window's pixels with ground truth; errors where both answer
    let (mut n_gt, mut n_main, mut n_fov, mut common) = (0u64, 0u64, 0u64, 0u64);
    let (mut e_main, mut e_fov, mut b_main, mut b_fov) = (0f64, 0f64, 0u64, 0u64);
    for v in 0..h {
        for u in 0..w {
            let i = ((y0 + v) * iw + x0 + u) as usize;
            let g = gt[i];
            if !g.is_finite() {
                continue;
            }
            n_gt += 1;
            let (m, f) = (up[i], fovea[(v * w + u) as usize]);
            n_main += m.is_finite() as u64;
            n_fov += f.is_finite() as u64;
            if m.is_finite() && f.is_finite() {
                common += 1;
                let (em, ef) = ((m - g).abs() as f64, (f - g).abs() as f64);
                e_main += em;
                e_fov += ef;
                b_main += (em > 1.0) as u64;
                b_fov += (ef > 1.0) as u64;
            }
        }
    }
    let c = common.max(1) as f64;
    let score = |answered: u64, e: f64, b: u64| MapScore {
        density: answered as f64 / n_gt.max(1) as f64,
        epe_px: e / c,
        bad1_pct: 100.0 * b as f64 / c,
    };
    let (main_s, fovea_s) = (score(n_main, e_main, b_main), score(n_fov, e_fov, b_fov));
    Ok(FoveaEval {
        size: [iw, ih],
        window: [x0, y0, w, h],
        main_resolution: [mw, mh],
        engine: est.engine,
        min_confidence: DEFAULT_MIN_CONFIDENCE,
        search_px: [start, start + range as f64],
        from_main,
        filled_from_main: filled,
        overruled_by_main: overruled,
        masked_by_main: masked,
        gt_pixels: n_gt,
        common_pixels: common,
        epe_ratio: fovea_s.epe_px / main_s.epe_px,
        main: main_s,
        fovea: fovea_s,
    })
}
