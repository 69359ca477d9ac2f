//! The one disparity score against ground truth (EPE and bad-k), used by `abvs disparity-eval`
//! and the disparity tests.

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
}
