//! The census-refine engine's per-pixel confidence, from what one run of it computes anyway (no second run,
//! unlike the left-right check of [`crate::confidence`]): a logistic model of whether the pixel is right to
//! 2 px, fitted on the development pair (Aloe at 640x480) over these features of the search's pass:
//!
//! - `acc`: whether SGBM's own checks (uniqueness, left-right, speckles) accepted the pixel as the search's
//!   start (1), or the network filled it (0);
//! - `m`: the census search's margin, how much better its winner is than the best offset beyond the winner's
//!   neighbours, `(second - best) / second` in [0, 1];
//! - `edge`: whether the winner is an end of the search window (the true match may lie beyond it);
//! - `span`: how far the 4-neighbours' disparities spread (px): a depth edge, where the answer (upsampled
//!   bilinearly) puts pixels between the two surfaces;
//! - `agree`: |refined - network| (px, at most 20), the network's own answer against the refined one.
//!
//! ```text
//! c = 1 / (1 + exp(-(B + W_ACC acc + W_MARGIN m + W_EDGE edge + W_SPAN ln(1 + span) + W_AGREE ln(1 + agree))))
//! 0 without a disparity or where the match falls outside the right image
//! ```
//!
//! Fitted by Newton's method on every Aloe pixel with ground truth (bad-2 as the label;
//! scripts/fit_census_confidence.py prints these weights and the mask's curve). The features were
//! chosen by fitting on one half of the image and ranking the other; the margin, SGBM's acceptance and the
//! depth edge carry most of it. Texture and the share of SGBM-accepted neighbours ranked Aloe a little better
//! (bad-2 at SGBM_3WAY's density on the lower half 2.4 against 3.0 %) but only with negative weights (a flat
//! region more confident than a textured one), which would publish the streaks of textureless walls: left
//! out. A flat region's ambiguity is in its margin (m = 0 scores 0.47 without SGBM's acceptance, below the
//! default threshold). Without an SGBM prior (the engine at its network's resolution) every pixel scores as
//! accepted (not calibrated there). Motorcycle is held out (cli/tests/disparity_real.rs). Each pixel also gets
//! the reason its confidence is not higher ([`reason`]): low texture, ambiguous, out of range, occluded /
//! depth edge.
use crate::confidence::reason;

/// The logistic model's bias (see the module docs; fitted on Aloe at 640x480).
pub const B: f32 = -0.13;
/// Weight of SGBM's acceptance.
pub const W_ACC: f32 = 0.5969;
/// Weight of the census margin.
pub const W_MARGIN: f32 = 6.1314;
/// Weight of a winner at the search window's end.
pub const W_EDGE: f32 = -0.3952;
/// Weight of ln(1 + the neighbours' span).
pub const W_SPAN: f32 = -1.5108;
/// Weight of ln(1 + |refined - network|).
pub const W_AGREE: f32 = -0.1575;
/// Below this texture (mean gray levels) a doubtful pixel's reason is low texture, not ambiguity.
pub const TEXTURE_LOW: f32 = 4.0;
/// Below this margin a pixel's reason is ambiguity (or low texture).
pub const MARGIN_LOW: f32 = 0.175;
/// Steps of the tables of ln(1 + v) for the span and the agreement (per px) and their reach (px).
const LN_STEPS: f32 = 32.0;
const LN_REACH: f32 = 64.0;

/// The margin of a search outcome byte that stands for 1 (the second best infinitely worse). The byte is
/// what census-refine's search ([`crate::census`]) records per pixel and this scoring reads: the winner's
/// margin in 1/`MARGIN_ONE` steps (0 ..= 127) and [`AT_EDGE`].
pub const MARGIN_ONE: u32 = 127;
/// The window-edge bit of a search outcome byte (the winner is an end of the search window).
pub const AT_EDGE: u8 = 0x80;

/// Buffers of the scoring at one resolution, allocated once.
pub struct Scorer {
    w: usize,
    h: usize,
    /// Horizontal 5-box sums of |I(x+1) - I(x-1)| per row.
    rows: Vec<u16>,
    /// W_MARGIN m of each margin byte; ln(1 + v) at 1 / LN_STEPS px (a logarithm per pixel costs more than
    /// the rest of the scoring).
    margin_term: [f32; 128],
    ln1p: Vec<f32>,
}

impl Scorer {
    /// A scorer for `w` x `h` maps.
    pub fn new(w: usize, h: usize) -> Scorer {
        Scorer {
            w,
            h,
            rows: vec![0; w * h],
            margin_term: std::array::from_fn(|m| W_MARGIN * m as f32 / MARGIN_ONE as f32),
            ln1p: (0..=(LN_STEPS * LN_REACH) as usize).map(|i| (i as f32 / LN_STEPS).ln_1p()).collect(),
        }
    }

    /// ln(1 + v) for v >= 0 from the table (v beyond its reach: its end).
    #[inline(always)]
    fn ln1p(&self, v: f32) -> f32 {
        self.ln1p[((v * LN_STEPS + 0.5) as usize).min(self.ln1p.len() - 1)]
    }

    /// The 5x5 box sum of the gradient at column `x` over rows `ys` (only for a doubtful pixel's reason).
    #[inline(always)]
    fn texture(&self, ys: &[usize; 5], x: usize) -> usize {
        ys.iter().map(|&yy| self.rows[yy * self.w + x] as usize).sum()
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
                let s = stat[i];
                let agree = (d - net[i]).abs();
                let agree = if agree.is_finite() { agree.min(20.0) } else { 20.0 };
                // no prior: nothing contradicts the network, its pixels score as accepted ones
                let accepted = prior.is_none_or(|p| p[i].is_finite());
                let nb = [
                    refined[up + x],
                    refined[down + x],
                    refined[y * w + x.saturating_sub(1)],
                    refined[y * w + (x + 1).min(w - 1)],
                ];
                let (lo, hi) = nb
                    .iter()
                    .fold((d, d), |(lo, hi), v| if v.is_finite() { (lo.min(*v), hi.max(*v)) } else { (lo, hi) });
                let beyond = s & AT_EDGE != 0;
                let z = B
                    + if accepted { W_ACC } else { 0.0 }
                    + self.margin_term[(s & !AT_EDGE) as usize]
                    + if beyond { W_EDGE } else { 0.0 }
                    + W_SPAN * self.ln1p(hi - lo)
                    + W_AGREE * self.ln1p(agree);
                conf[i] = 1.0 / (1.0 + (-z).exp());
                // the weakest evidence names the reason
                let m = (s & !AT_EDGE) as f32 / MARGIN_ONE as f32;
                why[i] = if beyond {
                    reason::OUT_OF_RANGE
                } else if m < MARGIN_LOW && (self.texture(&ys, x) as f32) < 25.0 * TEXTURE_LOW {
                    reason::LOW_TEXTURE
                } else if m < MARGIN_LOW {
                    reason::AMBIGUOUS
                } else {
                    reason::OCCLUDED
                };
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use abvs_runtime_core::params::DEFAULT_MIN_CONFIDENCE;

    /// A textured row band whose search was unique, started from an accepted SGBM match: high confidence;
    /// the same where the network filled a flat area with an ambiguous search: below the default threshold, for
    /// low texture.
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
        assert!(conf[j] < DEFAULT_MIN_CONFIDENCE, "{}", conf[j]);
        assert_eq!(why[j], reason::LOW_TEXTURE);
        // the left columns whose match leaves the right image
        assert_eq!((conf[3 * w + 2], why[3 * w + 2]), (0.0, reason::OUTSIDE_RIGHT));
    }
}
