//! The census-refine engine's per-pixel confidence, from what one run of it computes anyway (no second run,
//! unlike the left-right check of [`super::confidence`]):
//!
//! - whether SGBM's own checks (uniqueness, left-right, speckles) accepted the pixel as the search's start,
//!   or the network filled it;
//! - the census search's margin: how much better its winner is than the best offset beyond the winner's
//!   neighbours, `(second - best) / second`, and whether the winner is an end of the search window (the
//!   true match may lie beyond it);
//! - texture: the mean absolute horizontal gradient in a 5x5 box of the left image;
//! - agreement between the network's own answer and the refined one;
//! - a depth edge: neighbours that differ by more than [`EDGE_PX`] (the answer is upsampled bilinearly,
//!   which puts pixels between the two surfaces).
//!
//! ```text
//! m = min(1, margin / MARGIN_FULL)     t = min(1, texture / TEXTURE_FULL)     a = exp(-|refined - network| / AGREE_PX)
//! SGBM accepted:   c = 0.5 + 0.25 m + 0.25 a
//! network filled:  c = 0.5 m t a          (without an SGBM prior, every pixel scores as accepted)
//! times EDGE_FACTOR at a depth edge, times EDGE_FACTOR at the search window's end; 0 without a disparity or
//! where the match falls outside the right image
//! ```
//!
//! Each pixel also gets the reason its confidence is not higher ([`reason`]): low texture, ambiguous, out of
//! range, occluded. The constants and [`DEFAULT_MIN_CONFIDENCE`] were chosen on Aloe (opencv-doc) and the
//! rendered fixture; Motorcycle is held out (cli/tests/disparity_real.rs).
use super::confidence::reason;
use super::disparity_census::{AT_EDGE, MARGIN_ONE};

/// The default threshold of the validity mask (`[disparity] min_confidence`, `--min-confidence`): published
/// depth is NaN where the confidence is below it. 0 keeps every pixel (the dense output, bit for bit).
/// Chosen on Aloe at 640x480 (`abvs disparity-eval --resolution 640x480`, JSON `own_confidence.mask_curve`):
/// the threshold closest above SGBM_3WAY's density (0.725): density 0.733, bad-2 among the kept 4.48 %
/// against SGBM_3WAY's 3.85 % (0.25: 0.833 / 8.02 %; 0.35: 0.788 / 6.65 %; dense: 17.25 %).
pub const DEFAULT_MIN_CONFIDENCE: f32 = 0.4;
/// The census margin that counts as fully unique.
pub const MARGIN_FULL: f32 = 0.35;
/// The texture (mean |I(x+1) - I(x-1)|, gray levels) that counts as fully textured.
pub const TEXTURE_FULL: f32 = 8.0;
/// Scale (px at the search's resolution) of the agreement between the network and the refined answer.
pub const AGREE_PX: f32 = 1.0;
/// A pixel whose 4-neighbours' disparities span more than this (px at the search's resolution) is on a
/// depth edge.
pub const EDGE_PX: f32 = 1.5;
/// What a depth edge, or a winner at the search window's end, multiplies the confidence by.
pub const EDGE_FACTOR: f32 = 0.5;

/// Buffers of the scoring at one resolution, allocated once.
pub struct Scorer {
    w: usize,
    h: usize,
    /// Horizontal 5-box sums of |I(x+1) - I(x-1)| per row.
    rows: Vec<u16>,
}

impl Scorer {
    /// A scorer for `w` x `h` maps.
    pub fn new(w: usize, h: usize) -> Scorer {
        Scorer { w, h, rows: vec![0; w * h] }
    }

    /// Confidence and reason of each pixel of `refined` (this scorer's size): `img` the left image searched,
    /// `stat` the search's outcome bytes, `net` the network's own answer, `prior` SGBM's accepted matches
    /// (NaN where rejected) when the engine has them.
    #[allow(clippy::too_many_arguments)]
    pub fn score(
        &mut self,
        img: &[u8],
        stat: &[u8],
        refined: &[f32],
        net: &[f32],
        prior: Option<&[f32]>,
        conf: &mut [f32],
        why: &mut [u8],
    ) {
        let (w, h) = (self.w, self.h);
        // horizontal box sums of the central gradient
        for (src, dst) in img.chunks_exact(w).zip(self.rows.chunks_exact_mut(w)).take(h) {
            let g = |x: usize| src[(x + 1).min(w - 1)].abs_diff(src[x.saturating_sub(1)]) as u16;
            let mut s: u16 = (0..3.min(w)).map(g).sum::<u16>() + g(0) * 2;
            for (x, d) in dst.iter_mut().enumerate() {
                *d = s;
                s = s + g((x + 3).min(w - 1)) - g(x.saturating_sub(2));
            }
        }
        let margin_one = MARGIN_ONE as f32;
        for y in 0..h {
            let ys = [y.saturating_sub(2), y.saturating_sub(1), y, (y + 1).min(h - 1), (y + 2).min(h - 1)];
            let up = y.saturating_sub(1) * w;
            let down = (y + 1).min(h - 1) * w;
            for x in 0..w {
                let i = y * w + x;
                let d = refined[i];
                if !d.is_finite() {
                    (conf[i], why[i]) = (0.0, reason::NO_ESTIMATE);
                    continue;
                }
                if (x as f32) - d < 0.0 {
                    (conf[i], why[i]) = (0.0, reason::OUTSIDE_RIGHT);
                    continue;
                }
                let tex: u32 = ys.iter().map(|&yy| self.rows[yy * w + x] as u32).sum();
                let t = (tex as f32 / 25.0 / TEXTURE_FULL).min(1.0);
                let s = stat[i];
                let m = (((s & !AT_EDGE) as f32 / margin_one) / MARGIN_FULL).min(1.0);
                let a = (-(d - net[i]).abs() / AGREE_PX).exp();
                let a = if a.is_finite() { a } else { 0.0 };
                // Without a prior (the engine at its network's resolution: no SGBM ran) nothing contradicts
                // the network, so its pixels score as accepted ones; the mask then removes only ambiguous,
                // edge and out-of-range ones. The "network filled" score was calibrated where SGBM declined.
                let accepted = prior.is_none_or(|p| p[i].is_finite());
                let mut c = if accepted { 0.5 + 0.25 * m + 0.25 * a } else { 0.5 * m * t * a };
                let nb = [
                    refined[up + x],
                    refined[down + x],
                    refined[y * w + x.saturating_sub(1)],
                    refined[y * w + (x + 1).min(w - 1)],
                ];
                let (lo, hi) = nb
                    .iter()
                    .fold((d, d), |(lo, hi), v| if v.is_finite() { (lo.min(*v), hi.max(*v)) } else { (lo, hi) });
                let edge = hi - lo > EDGE_PX;
                let beyond = s & AT_EDGE != 0;
                if edge {
                    c *= EDGE_FACTOR;
                }
                if beyond {
                    c *= EDGE_FACTOR;
                }
                conf[i] = c;
                // the weakest evidence names the reason
                why[i] = if !accepted && t < 0.5 {
                    reason::LOW_TEXTURE
                } else if beyond {
                    reason::OUT_OF_RANGE
                } else if m < 0.5 {
                    reason::AMBIGUOUS
                } else {
                    reason::OCCLUDED
                };
            }
        }
    }
}

/// The validity mask: every pixel of `disparity` whose confidence is below `min` becomes NaN (`min` 0:
/// none is touched, the dense map bit for bit); the reason of each pixel kept with a disparity becomes
/// `VALID`, the others keep theirs (`NO_ESTIMATE` where the engine had no disparity).
pub fn mask(conf: &[f32], min: f32, disparity: &mut [f32], why: &mut [u8]) {
    for ((d, c), r) in disparity.iter_mut().zip(conf).zip(why.iter_mut()) {
        if !d.is_finite() {
            if *r == reason::VALID {
                *r = reason::NO_ESTIMATE;
            }
        } else if *c >= min {
            *r = reason::VALID;
        } else if min > 0.0 {
            *d = f32::NAN;
        }
    }
}

/// Nearest-neighbour resample of a `(sw, sh)` map into `(dw, dh)`.
pub fn nearest<T: Copy>(src: &[T], (sw, sh): (usize, usize), dst: &mut [T], (dw, dh): (usize, usize)) {
    for (y, row) in dst.chunks_exact_mut(dw).enumerate().take(dh) {
        let sy = (y * sh / dh).min(sh - 1);
        let s = &src[sy * sw..(sy + 1) * sw];
        for (x, o) in row.iter_mut().enumerate() {
            *o = s[(x * sw / dw).min(sw - 1)];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A textured row band whose search was unique, started from an accepted SGBM match: high confidence;
    /// the same where the network filled a flat area with an ambiguous search: low, for low texture.
    #[test]
    fn accepted_unique_matches_score_high_and_flat_ambiguous_ones_low() {
        let (w, h) = (16usize, 8usize);
        let img: Vec<u8> = (0..w * h).map(|i| if (i % w) < 8 { ((i * 37) % 200) as u8 } else { 100 }).collect();
        let refined = vec![4.0f32; w * h];
        let net = vec![4.2f32; w * h];
        let stat: Vec<u8> = (0..w * h).map(|i| if (i % w) < 8 { 60 } else { 5 }).collect();
        let prior: Vec<f32> = (0..w * h).map(|i| if (i % w) < 8 { 4.0 } else { f32::NAN }).collect();
        let (mut conf, mut why) = (vec![0f32; w * h], vec![0u8; w * h]);
        Scorer::new(w, h).score(&img, &stat, &refined, &net, Some(&prior), &mut conf, &mut why);
        let i = 3 * w + 6;
        assert!(conf[i] > 0.9, "{}", conf[i]);
        let j = 3 * w + 13;
        assert!(conf[j] < 0.05, "{}", conf[j]);
        assert_eq!(why[j], reason::LOW_TEXTURE);
        // the left columns whose match leaves the right image
        assert_eq!((conf[3 * w + 2], why[3 * w + 2]), (0.0, reason::OUTSIDE_RIGHT));
    }
}
