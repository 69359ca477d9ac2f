//! The census-refine engine's per-pixel confidence, from what one run of it computes anyway (no second run,
//! unlike the left-right check of [`crate::confidence`]): a logistic model of whether the pixel is right to
//! 2 px, fitted on the development pair (Aloe at 640x480) over these features. Of the search's pass (at the
//! network's resolution for the runtime's default, the grid the confidence is scored on and upsampled from):
//!
//! - `acc`: whether SGBM's own checks (uniqueness, left-right, speckles) accepted the pixel as the search's
//!   start (1), or the network filled it (0);
//! - `m`: the census search's margin, how much better its winner is than the best offset beyond the winner's
//!   neighbours, `(second - best) / second` in [0, 1];
//! - `span`: how far the 4-neighbours' disparities spread (px): a depth edge, where the answer (upsampled
//!   bilinearly) puts pixels between the two surfaces;
//! - `agree`: |refined - network| (px, at most 20), the network's own answer against the refined one;
//!
//! and of the published answer at the published resolution, pooled onto that grid:
//!
//! - `cost`: its census match cost ([`crate::match_cost`], in [0, 1]);
//! - `curv`: that cost's curvature about the answer, `(S2 - S1) / S2` of the pooled costs one and two pixels
//!   either side ([`crate::match_cost::Pooled::curv`], in [-1, 1]): a right answer sits in a basin of the
//!   cost, a wrong one (flat or repetitive texture, a surface the upsampling bent) does not.
//!
//! ```text
//! c = 1 / (1 + exp(-(B + W_ACC acc + W_MARGIN m + W_SPAN ln(1 + span) + W_AGREE ln(1 + agree) + W_COST cost
//!                    + W_CURV curv)))
//! 0 without a disparity or where the match falls outside the right image
//! ```
//!
//! Fitted by Newton's method on every Aloe pixel with ground truth (bad-2 as the label;
//! scripts/fit_census_confidence.py prints these weights and the mask's curve). The features were chosen by
//! fitting on one half of the image and ranking the other (bad-2 among the 72.5 % most confident of the
//! held-back upper / lower half, docs/depth.md): the search's features alone 3.01 / 0.90 %, with the match
//! cost 2.20 / 0.55 % (2.23 / 0.55 % with the cost on one row of each grid cell, as shipped), with its
//! curvature too 1.73 / 0.24 %. The cost, its curvature and the margin carry most of it. Whether the winner
//! is at the search window's end took a weight of +0.03 once the cost was in: left out of the model, it still
//! names a pixel's reason.
//! Texture and the share of SGBM-accepted neighbours ranked Aloe a little better without the cost, but only
//! with negative weights (a flat region more confident than a textured one), which would publish the streaks
//! of textureless walls: left out. A flat region's ambiguity is in its margin and its cost (a uniform patch
//! matches at chance at every offset: m = 0, cost 0.5 and curvature 0 score 0.34, below the default
//! threshold). Without an SGBM prior (the engine at its network's resolution) every pixel scores as accepted
//! (not calibrated there). Motorcycle is
//! held out (cli/tests/disparity_real.rs). Each pixel also gets the reason its confidence is not higher
//! ([`reason`]): low texture, ambiguous, out of range, occluded / depth edge.
//!
//! Cost: the scoring and the match cost's census run on the engine's second thread while the answer is
//! upsampled (disparity/examples/confidence_cost.rs measures what they add to the frame).
use crate::confidence::reason;
use crate::match_cost::Pooled;

/// The logistic model's bias (see the module docs; fitted on Aloe at 640x480).
pub const B: f32 = 2.5337;
/// Weight of SGBM's acceptance.
pub const W_ACC: f32 = 0.1474;
/// Weight of the census margin.
pub const W_MARGIN: f32 = 1.9847;
/// Weight of ln(1 + the neighbours' span).
pub const W_SPAN: f32 = -1.0778;
/// Weight of ln(1 + |refined - network|).
pub const W_AGREE: f32 = -0.1132;
/// Weight of the match cost at the published resolution ([`crate::match_cost`], in [0, 1]).
pub const W_COST: f32 = -6.3966;
/// Weight of the match cost's curvature about the answer ([`crate::match_cost::Pooled::curv`], in [-1, 1]).
pub const W_CURV: f32 = 3.6942;
/// Below this texture (mean gray levels) a doubtful pixel's reason is low texture, not ambiguity.
pub const TEXTURE_LOW: f32 = 4.0;
/// Below this margin a pixel's reason is ambiguity (or low texture).
pub const MARGIN_LOW: f32 = 0.175;
/// Where ln(1 + v) of the span and the agreement stops growing (px).
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
    /// One row's |I(x+1) - I(x-1)|, two clamped values either side.
    grad: Vec<u16>,
}

/// ln(1 + v) for 0 <= v (at most [`LN_REACH`]): the exponent of 1 + v and 2 atanh(s) of its mantissa's
/// s = (m - 1) / (m + 1) <= 1/3 to s^9 (within 1e-6). Straight-line arithmetic that vectorises, unlike
/// libm's call (a logarithm per pixel cost more than the rest of the scoring).
#[inline(always)]
fn ln1p(v: f32) -> f32 {
    let a = 1.0 + v.min(LN_REACH);
    let bits = a.to_bits();
    let e = ((bits >> 23) as i32 - 127) as f32;
    let m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000);
    let s = (m - 1.0) / (m + 1.0);
    let s2 = s * s;
    let p = 1.0 + s2 * (1.0 / 3.0 + s2 * (1.0 / 5.0 + s2 * (1.0 / 7.0 + s2 * (1.0 / 9.0))));
    e * std::f32::consts::LN_2 + 2.0 * s * p
}

/// The logistic function 1 / (1 + e^-z), with e^-z as 2^n 2^f: n by rounding with the 1.5 2^23 trick (no
/// rounding instruction on the baseline x86-64 target) and 2^f, |f| <= 1/2, by its Taylor series to f^7
/// (relative error below 1e-7). Vectorises; within 1e-6 of the exact function.
#[inline(always)]
pub fn logistic(z: f32) -> f32 {
    const ROUND: f32 = 12_582_912.0; // 1.5 2^23
    let t = (-z * std::f32::consts::LOG2_E).clamp(-126.0, 126.0);
    let n = (t + ROUND) - ROUND;
    let f = (t - n) * std::f32::consts::LN_2;
    let p = 1.0
        + f * (1.0
            + f * (0.5
                + f * (1.0 / 6.0 + f * (1.0 / 24.0 + f * (1.0 / 120.0 + f * (1.0 / 720.0 + f * (1.0 / 5040.0)))))));
    // n from the bits of t + ROUND (its low mantissa bits), not a float-to-int cast: Rust's saturating cast
    // does not vectorise
    let k = (t + ROUND).to_bits().wrapping_sub(ROUND.to_bits()) as i32;
    let two_n = f32::from_bits(((k + 127) as u32) << 23);
    1.0 / (1.0 + p * two_n)
}

/// One pixel's logit without the match cost (-inf: confidence 0) and its reason, from its refined disparity
/// `d`, its 4-neighbours' `nb`, its column `x`, search outcome byte `s`, the network's answer `net`, whether
/// SGBM accepted it, and its 5x5 gradient sum `tex`. Branch-free (selects), so that rows vectorise: NaN
/// neighbours drop out of the span through min / max, a NaN agreement counts as the most.
#[inline(always)]
fn pixel(d: f32, nb: [f32; 4], x: f32, s: u8, net: f32, accepted: bool, tex: u32) -> (f32, u8) {
    let (lo, hi) = (d.min(nb[0]).min(nb[1]).min(nb[2]).min(nb[3]), d.max(nb[0]).max(nb[1]).max(nb[2]).max(nb[3]));
    let agree = (d - net).abs().min(20.0);
    let m = (s & !AT_EDGE) as f32 / MARGIN_ONE as f32;
    let z = B + if accepted { W_ACC } else { 0.0 } + W_MARGIN * m + W_SPAN * ln1p(hi - lo) + W_AGREE * ln1p(agree);
    let known = !d.is_nan();
    let inside = x >= d;
    let low_m = m < MARGIN_LOW;
    // the weakest evidence names the reason
    let why = if s & AT_EDGE != 0 {
        reason::OUT_OF_RANGE
    } else if low_m && tex < (25.0 * TEXTURE_LOW) as u32 {
        reason::LOW_TEXTURE
    } else if low_m {
        reason::AMBIGUOUS
    } else {
        reason::OCCLUDED
    };
    let why = if !known {
        reason::NO_ESTIMATE
    } else if !inside {
        reason::OUTSIDE_RIGHT
    } else {
        why
    };
    (if known && inside { z } else { f32::NEG_INFINITY }, why)
}

impl Scorer {
    /// A scorer for `w` x `h` maps.
    pub fn new(w: usize, h: usize) -> Scorer {
        Scorer { w, h, rows: vec![0; w * h], grad: vec![0; w + 4] }
    }

    /// The search's part of the confidence's logit (`z`, -inf where the confidence is 0) and the reason of
    /// each pixel of `refined` (this scorer's size): `img` the left image searched, `stat` the search's
    /// outcome bytes, `net` the network's own answer, `prior` SGBM's accepted matches (NaN where rejected)
    /// when the engine has them. [`Scorer::finish`] adds the match cost and makes it a confidence.
    #[allow(clippy::too_many_arguments)]
    pub fn score(
        &mut self,
        img: &[u8],
        stat: &[u8],
        refined: &[f32],
        net: &[f32],
        prior: Option<&[f32]>,
        z: &mut [f32],
        why: &mut [u8],
    ) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has the instruction set the function is compiled for (checked just above).
            unsafe { score_avx2(self, img, stat, refined, net, prior, z, why) };
            return;
        }
        score_generic(self, img, stat, refined, net, prior, z, why)
    }

    /// The confidence of each pixel from its logit `z` (from [`Scorer::score`]), its match cost and the cost's
    /// curvature (`m`, [`crate::match_cost`]), in place.
    pub fn finish(z: &mut [f32], m: Pooled<'_>) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: as in `score`.
            unsafe { finish_avx2(z, m) };
            return;
        }
        finish_generic(z, m)
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
unsafe fn score_avx2(
    s: &mut Scorer,
    img: &[u8],
    stat: &[u8],
    refined: &[f32],
    net: &[f32],
    prior: Option<&[f32]>,
    z: &mut [f32],
    why: &mut [u8],
) {
    score_generic(s, img, stat, refined, net, prior, z, why)
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn score_generic(
    s: &mut Scorer,
    img: &[u8],
    stat: &[u8],
    refined: &[f32],
    net: &[f32],
    prior: Option<&[f32]>,
    z: &mut [f32],
    why: &mut [u8],
) {
    let (w, h) = (s.w, s.h);
    // horizontal 5-box sums of the central gradient, the window clamped at the row's ends: the gradient into a
    // row padded by two clamped values each side, then five shifted slices summed (straight loops that vectorise;
    // a running sum, one pixel after the other, took 40 % of the scoring)
    let gp = &mut s.grad;
    for (src, dst) in img.chunks_exact(w).zip(s.rows.chunks_exact_mut(w)).take(h) {
        let g = |x: usize| src[(x + 1).min(w - 1)].abs_diff(src[x.saturating_sub(1)]) as u16;
        gp[2] = g(0);
        if w > 2 {
            for ((o, a), b) in gp[3..w + 1].iter_mut().zip(&src[2..w]).zip(&src[..w - 2]) {
                *o = a.abs_diff(*b) as u16;
            }
        }
        gp[w + 1] = g(w - 1);
        (gp[0], gp[1], gp[w + 2], gp[w + 3]) = (gp[2], gp[2], gp[w + 1], gp[w + 1]);
        let (g0, g1, g2, g3, g4) = (&gp[..w], &gp[1..w + 1], &gp[2..w + 2], &gp[3..w + 3], &gp[4..w + 4]);
        for x in 0..w {
            dst[x] = g0[x] + g1[x] + g2[x] + g3[x] + g4[x];
        }
    }
    for y in 0..h {
        let row = |v: usize| v * w..(v + 1) * w;
        let (r, up, down) = (&refined[row(y)], &refined[row(y.saturating_sub(1))], &refined[row((y + 1).min(h - 1))]);
        let (st, nt) = (&stat[row(y)], &net[row(y)]);
        let t: [&[u16]; 5] = std::array::from_fn(|k| &s.rows[row((y + k).saturating_sub(2).min(h - 1))]);
        let (zr, wr) = (&mut z[row(y)], &mut why[row(y)]);
        // no prior: nothing contradicts the network, its pixels score as accepted ones
        let pr = prior.map(|p| &p[row(y)]);
        let tex = |x: usize| t[0][x] as u32 + t[1][x] as u32 + t[2][x] as u32 + t[3][x] as u32 + t[4][x] as u32;
        let ends = if w > 1 { [0, w - 1] } else { [0, 0] };
        for x in ends {
            let nb = [up[x], down[x], r[x.saturating_sub(1)], r[(x + 1).min(w - 1)]];
            let acc = pr.is_none_or(|p| !p[x].is_nan());
            (zr[x], wr[x]) = pixel(r[x], nb, x as i32 as f32, st[x], nt[x], acc, tex(x));
        }
        // the interior in one straight loop (shifted slices, no clamping) that the compiler vectorises
        if w > 2 {
            let (r, up, down, st, nt) = (&r[..w], &up[..w], &down[..w], &st[..w], &nt[..w]);
            let (t0, t1, t2, t3, t4) = (&t[0][..w], &t[1][..w], &t[2][..w], &t[3][..w], &t[4][..w]);
            let (zr, wr) = (&mut zr[..w], &mut wr[..w]);
            match pr {
                Some(p) => {
                    let p = &p[..w];
                    for x in 1..w - 1 {
                        let tex = t0[x] as u32 + t1[x] as u32 + t2[x] as u32 + t3[x] as u32 + t4[x] as u32;
                        let nb = [up[x], down[x], r[x - 1], r[x + 1]];
                        (zr[x], wr[x]) = pixel(r[x], nb, x as i32 as f32, st[x], nt[x], !p[x].is_nan(), tex);
                    }
                }
                None => {
                    for x in 1..w - 1 {
                        let tex = t0[x] as u32 + t1[x] as u32 + t2[x] as u32 + t3[x] as u32 + t4[x] as u32;
                        let nb = [up[x], down[x], r[x - 1], r[x + 1]];
                        (zr[x], wr[x]) = pixel(r[x], nb, x as i32 as f32, st[x], nt[x], true, tex);
                    }
                }
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn finish_avx2(z: &mut [f32], m: Pooled<'_>) {
    finish_generic(z, m)
}

#[inline(always)]
fn finish_generic(z: &mut [f32], m: Pooled<'_>) {
    for (c, (&m, &k)) in z.iter_mut().zip(m.cost.iter().zip(m.curv)) {
        let v = logistic(*c + W_COST * m + W_CURV * k);
        *c = if *c == f32::NEG_INFINITY { 0.0 } else { v };
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use abvs_runtime_core::params::DEFAULT_MIN_CONFIDENCE;

    /// The straight-line logistic function and logarithm are the functions, over the range they are used on.
    #[test]
    fn the_approximations_are_the_functions() {
        for i in -4000..=4000 {
            let z = i as f32 / 97.0;
            let want = 1.0 / (1.0 + (-(z as f64)).exp());
            assert!((logistic(z) as f64 - want).abs() < 1e-6, "{z}: {} vs {want}", logistic(z));
        }
        assert_eq!(logistic(-200.0), 1.0 / (1.0 + 2f32.powi(126)));
        assert!(logistic(200.0) > 0.999_999);
        for i in 0..=6400 {
            let v = i as f32 / 97.0;
            let want = (v.min(LN_REACH) as f64).ln_1p();
            assert!((ln1p(v) as f64 - want).abs() < 2e-6, "{v}: {} vs {want}", ln1p(v));
        }
        // -inf is no estimate: confidence 0 whatever the cost
        let mut z = [f32::NEG_INFINITY, 0.0];
        Scorer::finish(&mut z, Pooled { cost: &[0.0, 0.0], curv: &[1.0, 1.0] });
        assert_eq!(z[0], 0.0);
    }

    /// The texture rows (horizontal 5-box sums of |I(x+1) - I(x-1)|, both clamped at the row's ends) are their
    /// definition, at widths from one pixel up.
    #[test]
    fn texture_sums_are_the_definition() {
        for (w, h) in [(1usize, 2usize), (2, 1), (3, 3), (5, 2), (17, 4), (320, 3)] {
            let img: Vec<u8> = (0..w * h).map(|i| ((i * 7919 + (i / 5) * 104_729) % 256) as u8).collect();
            let mut s = Scorer::new(w, h);
            let n = w * h;
            let (mut z, mut why) = (vec![0f32; n], vec![0u8; n]);
            s.score(&img, &vec![0; n], &vec![1.0; n], &vec![1.0; n], None, &mut z, &mut why);
            for y in 0..h {
                let row = &img[y * w..(y + 1) * w];
                let g = |x: isize| {
                    let x = x.clamp(0, w as isize - 1) as usize;
                    row[(x + 1).min(w - 1)].abs_diff(row[x.saturating_sub(1)]) as u16
                };
                for x in 0..w {
                    let want: u16 = (-2..=2).map(|k| g(x as isize + k)).sum();
                    assert_eq!(s.rows[y * w + x], want, "{w}x{h} at ({x}, {y})");
                }
            }
        }
    }

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
        // the match cost (crate::match_cost): the textured band matched, the uniform one at chance
        let cost: Vec<f32> = (0..w * h).map(|i| if (i % w) < 8 { 0.05 } else { 0.5 }).collect();
        // a basin about the textured band's answer, none on the uniform band (the same cost at every offset)
        let curv: Vec<f32> = (0..w * h).map(|i| if (i % w) < 8 { 0.3 } else { 0.0 }).collect();
        Scorer::finish(&mut conf, Pooled { cost: &cost, curv: &curv });
        let i = 3 * w + 6;
        assert!(conf[i] > 0.9, "{}", conf[i]);
        let j = 3 * w + 13;
        assert!(conf[j] < DEFAULT_MIN_CONFIDENCE, "{}", conf[j]);
        assert_eq!(why[j], reason::LOW_TEXTURE);
        // the left columns whose match leaves the right image
        assert_eq!((conf[3 * w + 2], why[3 * w + 2]), (0.0, reason::OUTSIDE_RIGHT));
    }
}
