//! Scoring disparity maps against ground truth: the one EPE and bad-k score ([`score_disparity`]), what a
//! confidence is worth (bad-2 against density, kept in order of falling confidence), what is
//! published (density and bad-2 among the published pixels), the validity mask's curve, and the ground truth
//! itself read at an engine's resolution. `abvs disparity-eval` prints and plots them.
use std::path::Path;

use opencv::core::Mat;
use opencv::imgcodecs;
use opencv::prelude::*;

use crate::error::{cv, DisparityError, Result};
use crate::pfm::read_pfm;

/// Scores of a disparity map against ground truth, over the ground-truth pixels below the
/// engine's maximum disparity.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DisparityScore {
    /// Mean |d - gt| over the pixels the engine answered (px).
    pub epe_px: f64,
    /// bad-1, bad-2, bad-3: % of the scored pixels with error above 1, 2, 3 px; a pixel the
    /// engine left without an answer counts as bad.
    pub bad_pct: [f64; 3],
    /// Answered fraction of the scored pixels.
    pub valid_fraction: f64,
    /// Pixels scored: finite ground truth below `max_disp`.
    pub gt_pixels: usize,
}

/// Scores `d` (non-finite = no answer) against `gt` (non-finite = no truth), same layout.
pub fn score_disparity(d: &[f32], gt: &[f32], max_disp: f64) -> DisparityScore {
    let (mut n, mut both, mut sum, mut bad) = (0usize, 0usize, 0f64, [0usize; 3]);
    for (p, g) in d.iter().zip(gt) {
        if !(g.is_finite() && (*g as f64) < max_disp) {
            continue;
        }
        n += 1;
        if !p.is_finite() {
            bad.iter_mut().for_each(|b| *b += 1);
            continue;
        }
        let e = (p - g).abs() as f64;
        both += 1;
        sum += e;
        for (k, b) in bad.iter_mut().enumerate() {
            if e > (k + 1) as f64 {
                *b += 1;
            }
        }
    }
    let pct = |b: usize| 100.0 * b as f64 / n.max(1) as f64;
    DisparityScore {
        epe_px: sum / both.max(1) as f64,
        bad_pct: bad.map(pct),
        valid_fraction: both as f64 / n.max(1) as f64,
        gt_pixels: n,
    }
}

/// Ground truth at `w` x `h` (nearest neighbour, values scaled by the width ratio; NaN unknown), read from a
/// PFM (pixels; inf, NaN and 0 unknown) or an 8/16-bit single-channel image divided by `scale` (0 unknown);
/// with the file's own size.
pub fn load_gt(path: &Path, scale: f64, w: u32, h: u32) -> Result<(usize, usize, Vec<f32>)> {
    let bad = |msg: String| DisparityError::Format { path: path.to_path_buf(), msg };
    let cv = cv("ground truth");
    let (gw, gh, g) = if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("pfm")) {
        read_pfm(path)?
    } else {
        let name = path.to_str().ok_or_else(|| bad("path is not UTF-8".into()))?;
        let m = imgcodecs::imread(name, imgcodecs::IMREAD_UNCHANGED).map_err(&cv)?;
        if m.empty() || m.channels() != 1 {
            return Err(bad("not a single-channel ground-truth image".into()));
        }
        let mut f = Mat::default();
        m.convert_to(&mut f, opencv::core::CV_32F, 1.0 / scale, 0.0).map_err(&cv)?;
        let v: Vec<f32> =
            f.data_typed::<f32>().map_err(&cv)?.iter().map(|x| if *x > 0.0 { *x } else { f32::NAN }).collect();
        (m.cols() as usize, m.rows() as usize, v)
    };
    if gw == 0 || gh == 0 || g.len() < gw * gh {
        return Err(bad(format!("empty ground-truth image ({gw}x{gh})")));
    }
    if w == 0 || h == 0 {
        return Err(DisparityError::Invalid(format!("engine resolution {w}x{h} is empty")));
    }
    let sx = w as f32 / gw as f32;
    let mut out = vec![f32::NAN; w as usize * h as usize];
    for y in 0..h as usize {
        let yy = (((y as f32 + 0.5) * gh as f32 / h as f32) as usize).min(gh - 1);
        for x in 0..w as usize {
            let xx = (((x as f32 + 0.5) / sx) as usize).min(gw - 1);
            let v = g[yy * gw + xx];
            out[y * w as usize + x] = if v.is_finite() && v > 0.0 { v * sx } else { f32::NAN };
        }
    }
    Ok((gw, gh, out))
}

/// bad-2 (% of the ground-truth pixels kept) against density (fraction of ground-truth pixels kept), keeping
/// pixels in order of falling confidence; 0-confidence (invalid) pixels are never kept.
pub fn density_curve(d: &[f32], conf: &[f32], gt: &[f32], max_disp: f64) -> Vec<(f64, f64)> {
    let mut px: Vec<(f32, bool)> = Vec::new();
    let mut n = 0usize;
    for ((p, c), g) in d.iter().zip(conf).zip(gt) {
        if !(g.is_finite() && (*g as f64) < max_disp) {
            continue;
        }
        n += 1;
        if p.is_finite() && *c > 0.0 {
            px.push((*c, (p - g).abs() > 2.0));
        }
    }
    px.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut out = Vec::new();
    let mut bad = 0usize;
    let step = (n / 200).max(1);
    for (i, (_, b)) in px.iter().enumerate() {
        bad += *b as usize;
        if (i + 1) % step == 0 || i + 1 == px.len() {
            out.push(((i + 1) as f64 / n as f64, 100.0 * bad as f64 / (i + 1) as f64));
        }
    }
    out
}

/// Density (fraction of the ground-truth pixels with a published disparity) and bad-2 (%) among the
/// published ones: what a robot acts on.
pub fn published_score(d: &[f32], gt: &[f32], max_disp: f64) -> (f64, f64) {
    let (mut n, mut kept, mut bad) = (0usize, 0usize, 0usize);
    for (p, g) in d.iter().zip(gt) {
        if !(g.is_finite() && (*g as f64) < max_disp) {
            continue;
        }
        n += 1;
        if p.is_finite() {
            kept += 1;
            bad += ((p - g).abs() > 2.0) as usize;
        }
    }
    (kept as f64 / n.max(1) as f64, 100.0 * bad as f64 / kept.max(1) as f64)
}

/// The validity mask at each threshold of `thresholds`: (threshold, density, bad-2 % among the kept).
pub fn mask_curve(d: &[f32], conf: &[f32], gt: &[f32], max_disp: f64, thresholds: &[f32]) -> Vec<[f64; 3]> {
    thresholds
        .iter()
        .map(|&t| {
            let m: Vec<f32> = d.iter().zip(conf).map(|(v, c)| if *c >= t { *v } else { f32::NAN }).collect();
            let (dn, b) = published_score(&m, gt, max_disp);
            [t as f64, dn, b]
        })
        .collect()
}

/// bad-2 among the kept at `density` on a density curve (the last point at or below it).
pub fn bad2_at(curve: &[(f64, f64)], density: f64) -> Option<f64> {
    curve.iter().rev().find(|(dn, _)| *dn <= density).map(|(_, b)| *b)
}

/// The largest density on a density curve whose bad-2 among the kept is at most `bad` (0 if none).
pub fn density_at(curve: &[(f64, f64)], bad: f64) -> f64 {
    curve.iter().filter(|(_, b)| *b <= bad).map(|(dn, _)| *dn).fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_unanswered_as_bad_and_skips_truth_beyond_range() {
        let gt = [10.0, 10.0, 10.0, 10.0, f32::NAN, 200.0];
        let d = [10.5, 11.5, 13.5, f32::INFINITY, 3.0, 200.0];
        let s = score_disparity(&d, &gt, 192.0);
        assert_eq!(s.gt_pixels, 4);
        assert!((s.epe_px - 5.5 / 3.0).abs() < 1e-12);
        assert_eq!(s.bad_pct, [75.0, 50.0, 50.0]);
        assert_eq!(s.valid_fraction, 0.75);
    }

    #[test]
    fn load_gt_refuses_an_empty_image_instead_of_underflowing() {
        let dir = tempfile::tempdir().unwrap();
        // a PFM cannot be empty (its reader refuses 0), a PNG can be 0 pixels only by not decoding: both errors
        let p = dir.path().join("gt.pfm");
        std::fs::write(&p, b"Pf\n0 0\n-1.0\n").unwrap();
        assert!(load_gt(&p, 1.0, 8, 8).is_err());
        let p = dir.path().join("gt.png");
        std::fs::write(&p, b"").unwrap();
        assert!(load_gt(&p, 1.0, 8, 8).is_err());
        // a 1x1 ground truth scales to any size
        let p = dir.path().join("one.pfm");
        std::fs::write(&p, pfm_bytes(1, 1, &[2.0])).unwrap();
        let (_, _, g) = load_gt(&p, 1.0, 4, 3).unwrap();
        assert_eq!(g, vec![8.0; 12]);
        assert!(load_gt(&p, 1.0, 0, 3).is_err());
    }

    fn pfm_bytes(w: usize, h: usize, data: &[f32]) -> Vec<u8> {
        let mut b = format!("Pf\n{w} {h}\n-1.0\n").into_bytes();
        data.iter().for_each(|v| b.extend_from_slice(&v.to_le_bytes()));
        b
    }

    #[test]
    fn density_curve_keeps_the_most_confident_first() {
        let gt = [10.0, 10.0, 10.0, 10.0];
        let d = [10.0, 15.0, 10.5, f32::NAN];
        let conf = [0.9, 0.1, 0.5, 0.0];
        let c = density_curve(&d, &conf, &gt, 100.0);
        assert_eq!(c, vec![(0.25, 0.0), (0.5, 0.0), (0.75, 100.0 / 3.0)]);
        assert_eq!(density_at(&c, 10.0), 0.5);
        assert_eq!(density_at(&c, 0.0), 0.5);
        assert_eq!(density_at(&c[2..], 10.0), 0.0);
    }
}
