//! Per-pixel confidence of a disparity map by a left-right consistency check, for any
//! [`DisparityEngine`].
//!
//! The right view's disparity comes from the same engine on the mirrored, swapped pair: each row of the right
//! image mirrored is a left view of the mirrored left image, so `engine(mirror(right), mirror(left))`
//! mirrored back is the disparity of every right pixel (its match lies `d` to the right, in the left image).
//! A left pixel `x` with disparity `d` matches the right pixel `x - round(d)`; where both maps agree the match
//! is consistent:
//!
//! ```text
//! confidence(x) = exp(-|d_left(x) - d_right(x - round(d_left(x)))|)     in (0, 1]
//! ```
//! and 0 where the left disparity is NaN, its match falls outside the right image (`x - d < 0`), the right
//! view has no disparity there, or the two differ by more than `max_diff` px (occlusions, mismatches). Pixels
//! of the rectified left image that do not see the raw image get 0 too. With `invalidate`, every pixel of
//! confidence 0 also loses its disparity (NaN), so depth and cloud drop it.
//!
//! An engine that defines its own check ([`DisparityEngine::own_lr_check`]: the fused engine,
//! [`crate::fused`]) is checked by it instead; [`LrCheck`] is the one entry point of both, for
//! `abvs disparity`, `abvs disparity-eval` and the runtime's disparity stage alike.
//!
//! The check runs the engine a second time (about doubling the disparity stage) on mirror buffers allocated
//! at start: it does not allocate per frame. [`mask`] is the validity mask of an engine's own confidence
//! (census-refine's, [`crate::census_confidence`]). What the check does ([`CheckConfig`]) is plain data of the
//! runtime's bottom crate, which the deployment file fills.
use crate::engine::DisparityEngine;
use crate::error::{DisparityError, Result};
use abvs_runtime_core::params::{CheckConfig, MAX_DIFF_LIMIT};

/// Each row of a `width`-wide image reversed into `dst` (the mirror that turns a right view into a left one).
pub fn mirror_rows<T: Copy>(src: &[T], width: usize, dst: &mut [T]) {
    for (d, s) in dst.chunks_exact_mut(width).zip(src.chunks_exact(width)) {
        for (a, b) in d.iter_mut().zip(s.iter().rev()) {
            *a = *b;
        }
    }
}

/// Why a pixel has no checked disparity: the codes of `abvs disparity --invalid-reason`.
pub mod reason {
    /// The pixel has a checked disparity.
    pub const VALID: u8 = 0;
    /// The engine gave no disparity.
    pub const NO_ESTIMATE: u8 = 1;
    /// The match falls outside the right image.
    pub const OUTSIDE_RIGHT: u8 = 2;
    /// The right view's disparity there disagrees (occlusion or mismatch).
    pub const LR_FAILED: u8 = 3;
    /// The engine's own confidence is below the threshold, weakest for low texture (a flat area the
    /// network filled: [`crate::census_confidence`]).
    pub const LOW_TEXTURE: u8 = 4;
    /// ... for an ambiguous census search (its winner barely better than other offsets).
    pub const AMBIGUOUS: u8 = 5;
    /// ... for the search's winner at its window's end (the match may lie beyond the range searched).
    pub const OUT_OF_RANGE: u8 = 6;
    /// ... for SGBM's checks rejecting the pixel (left-right: occlusion) or a depth edge, the network's
    /// answer not confirmed.
    pub const OCCLUDED: u8 = 7;
}

/// The left-right check of a left-view disparity `left` against the right view's `right` (both
/// `width`-wide, row-major): writes each pixel's confidence into `conf` (see the module docs) and returns
/// how many pixels passed. With `invalidate`, the left disparity of every failing pixel becomes NaN.
pub fn lr_check(
    left: &mut [f32],
    right: &[f32],
    width: usize,
    max_diff: f32,
    invalidate: bool,
    conf: &mut [f32],
) -> usize {
    lr_check_with_reasons(left, right, width, max_diff, invalidate, conf, None)
}

/// [`lr_check`], also writing each pixel's [`reason`] code into `why` when given.
pub fn lr_check_with_reasons(
    left: &mut [f32],
    right: &[f32],
    width: usize,
    max_diff: f32,
    invalidate: bool,
    conf: &mut [f32],
    mut why: Option<&mut [u8]>,
) -> usize {
    let mut passed = 0;
    for (row, (l_row, c_row)) in left.chunks_exact_mut(width).zip(conf.chunks_exact_mut(width)).enumerate() {
        let r_row = &right[row * width..(row + 1) * width];
        for (x, (d, c)) in l_row.iter_mut().zip(c_row.iter_mut()).enumerate() {
            *c = 0.0;
            let code = if !d.is_finite() {
                reason::NO_ESTIMATE
            } else {
                let xr = (x as f32 - *d).round();
                if xr < 0.0 || xr >= width as f32 {
                    reason::OUTSIDE_RIGHT
                } else {
                    let diff = (*d - r_row[xr as usize]).abs();
                    // (a NaN right disparity fails the comparison)
                    if diff <= max_diff {
                        *c = (-diff).exp();
                        reason::VALID
                    } else {
                        reason::LR_FAILED
                    }
                }
            };
            if code == reason::VALID {
                passed += 1;
            } else if invalidate {
                *d = f32::NAN;
            }
            if let Some(w) = why.as_deref_mut() {
                w[row * width + x] = code;
            }
        }
    }
    passed
}

/// The validity mask: every pixel of `disparity` whose confidence is below `min` becomes NaN (`min` 0:
/// none is touched, the dense map bit for bit); the reason of each pixel kept with a disparity becomes
/// `VALID`, the others keep theirs (`NO_ESTIMATE` where the engine had no disparity).
pub fn mask(conf: &[f32], min: f32, disparity: &mut [f32], why: &mut [u8]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has the instruction set the function is compiled for (checked just above).
        unsafe { mask_avx2(conf, min, disparity, why) };
        return;
    }
    mask_generic(conf, min, disparity, why)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn mask_avx2(conf: &[f32], min: f32, disparity: &mut [f32], why: &mut [u8]) {
    mask_generic(conf, min, disparity, why)
}

/// [`mask`] of a copy: the engine's confidence `conf` and reasons `why` into `out_conf` and `out_why` (0 and
/// `NO_ESTIMATE` where `seen` is 0: a rectified pixel that does not see the raw image), masking `disparity`
/// at `min` in the same pass. The runtime's disparity stage: one pass over the frame's maps (0.2 ms a 640x480
/// frame on this project's VM) instead of a copy loop and a mask (0.6 and 0.66 ms before they vectorised).
pub fn mask_into(
    conf: &[f32],
    why: &[u8],
    seen: &[u8],
    min: f32,
    disparity: &mut [f32],
    out_conf: &mut [f32],
    out_why: &mut [u8],
) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has the instruction set the function is compiled for (checked just above).
        unsafe { mask_into_avx2(conf, why, seen, min, disparity, out_conf, out_why) };
        return;
    }
    mask_into_generic(conf, why, seen, min, disparity, out_conf, out_why)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn mask_into_avx2(
    conf: &[f32],
    why: &[u8],
    seen: &[u8],
    min: f32,
    disparity: &mut [f32],
    out_conf: &mut [f32],
    out_why: &mut [u8],
) {
    mask_into_generic(conf, why, seen, min, disparity, out_conf, out_why)
}

#[inline(always)]
fn mask_into_generic(
    conf: &[f32],
    why: &[u8],
    seen: &[u8],
    min: f32,
    disparity: &mut [f32],
    out_conf: &mut [f32],
    out_why: &mut [u8],
) {
    let drop = min > 0.0;
    let n = disparity.len().min(conf.len()).min(why.len()).min(seen.len()).min(out_conf.len()).min(out_why.len());
    let (conf, why, seen) = (&conf[..n], &why[..n], &seen[..n]);
    let (disparity, out_conf, out_why) = (&mut disparity[..n], &mut out_conf[..n], &mut out_why[..n]);
    for i in 0..n {
        // "seen or not" as a bit mask, not a select on a byte's truth: with selects the loop did not vectorise
        // (2.2 against 0.2 ms a 640x480 frame); the AND gives +0.0 where not seen, as the select would
        let m8 = 0u8.wrapping_sub((seen[i] != 0) as u8);
        let c = f32::from_bits(conf[i].to_bits() & (m8 as i8 as i32 as u32));
        let r = (why[i] & m8) | (reason::NO_ESTIMATE & !m8);
        let d = disparity[i];
        let finite = d.is_finite();
        let keep = c >= min;
        let kept = if keep { reason::VALID } else { r };
        let none = if r == reason::VALID { reason::NO_ESTIMATE } else { r };
        out_conf[i] = c;
        out_why[i] = if finite { kept } else { none };
        disparity[i] = if finite & !keep & drop { f32::NAN } else { d };
    }
}

/// [`mask`]'s loop: selects, not branches, over slices cut to one length, so that it vectorises (it runs on
/// every published pixel of every frame: 0.66 ms a 640x480 frame on this project's VM as a baseline-x86-64
/// loop, about a tenth of the confidence's cost in the paired benchmark).
#[inline(always)]
fn mask_generic(conf: &[f32], min: f32, disparity: &mut [f32], why: &mut [u8]) {
    let drop = min > 0.0;
    let n = disparity.len().min(conf.len()).min(why.len());
    let (disparity, conf, why) = (&mut disparity[..n], &conf[..n], &mut why[..n]);
    for i in 0..n {
        let (d, c, r) = (disparity[i], conf[i], why[i]);
        let finite = d.is_finite();
        let keep = c >= min;
        let kept = if keep { reason::VALID } else { r };
        let none = if r == reason::VALID { reason::NO_ESTIMATE } else { r };
        why[i] = if finite { kept } else { none };
        disparity[i] = if finite & !keep & drop { f32::NAN } else { d };
    }
}

/// The check's buffers at one resolution, allocated once.
pub struct LrCheck {
    /// What the check produces.
    pub cfg: CheckConfig,
    width: usize,
    left_m: Vec<u8>,
    right_m: Vec<u8>,
    disp_m: Vec<f32>,
    right_disp: Vec<f32>,
    /// Where the confidence goes when the caller does not keep it (`invalidate` only).
    scratch: Vec<f32>,
    /// The reasons when the caller does not keep them.
    why: Vec<u8>,
}

impl LrCheck {
    /// A check with `cfg` (refused when out of range); [`LrCheck::start`] sizes its buffers.
    pub fn new(cfg: CheckConfig) -> Result<LrCheck> {
        if !(cfg.max_diff > 0.0 && cfg.max_diff <= MAX_DIFF_LIMIT) {
            return Err(DisparityError::Invalid(format!(
                "left-right check: max_diff {} px must be in (0, {MAX_DIFF_LIMIT}]",
                cfg.max_diff
            )));
        }
        Ok(LrCheck {
            cfg,
            width: 0,
            left_m: Vec::new(),
            right_m: Vec::new(),
            disp_m: Vec::new(),
            right_disp: Vec::new(),
            scratch: Vec::new(),
            why: Vec::new(),
        })
    }

    /// Allocates the buffers for `width` x `height` images (at start, before any frame).
    pub fn start(&mut self, width: u32, height: u32) {
        let n = (width * height) as usize;
        self.width = width as usize;
        self.left_m = vec![0; n];
        self.right_m = vec![0; n];
        self.disp_m = vec![f32::NAN; n];
        self.right_disp = vec![f32::NAN; n];
        self.scratch = if self.cfg.confidence { Vec::new() } else { vec![0.0; n] };
        self.why = vec![reason::VALID; n];
    }

    /// Runs the check on a pair whose left-view disparity `engine` just computed into `disparity`: the
    /// engine's own check ([`DisparityEngine::own_lr_check`]) where it has one, else the right view's
    /// disparity through the same engine and [`lr_check`]. Confidence into `conf` (`None`: not kept, only
    /// with `invalidate`), reasons into `why` when given. `valid` (the rectified pixels that see the raw
    /// image) zeroes the confidence elsewhere: a pixel matched on padding. Returns how many pixels passed.
    #[allow(clippy::too_many_arguments)]
    pub fn run(
        &mut self,
        engine: &mut dyn DisparityEngine,
        left: &[u8],
        right: &[u8],
        valid: Option<&[u8]>,
        disparity: &mut [f32],
        conf: Option<&mut [f32]>,
        why: Option<&mut [u8]>,
    ) -> Result<usize> {
        let n = self.left_m.len();
        let sized = |l: Option<usize>| l.is_none_or(|l| l == n);
        if n == 0
            || disparity.len() != n
            || left.len() != n
            || right.len() != n
            || !sized(valid.map(|v| v.len()))
            || !sized(conf.as_ref().map(|c| c.len()))
            || !sized(why.as_ref().map(|w| w.len()))
            || (conf.is_none() && self.scratch.len() != n)
        {
            return Err(DisparityError::Invalid("left-right check: buffers not sized (not started?)".into()));
        }
        let conf: &mut [f32] = match conf {
            Some(c) => c,
            None => &mut self.scratch,
        };
        let why: &mut [u8] = match why {
            Some(w) => w,
            None => &mut self.why,
        };
        let (max_diff, invalidate) = (self.cfg.max_diff, self.cfg.invalidate);
        let mut passed = match engine.own_lr_check(max_diff, invalidate, disparity, conf, why) {
            Some(p) => p?,
            None => {
                let width = self.width;
                mirror_rows(right, width, &mut self.left_m);
                mirror_rows(left, width, &mut self.right_m);
                engine.compute(&self.left_m, &self.right_m, &mut self.disp_m)?;
                mirror_rows(&self.disp_m, width, &mut self.right_disp);
                lr_check_with_reasons(disparity, &self.right_disp, width, max_diff, invalidate, conf, Some(why))
            }
        };
        // a rectified pixel that does not see the raw image is matched on padding: no confidence
        if let Some(valid) = valid {
            for (((c, v), d), r) in conf.iter_mut().zip(valid).zip(disparity.iter_mut()).zip(why.iter_mut()) {
                if *v == 0 {
                    passed -= (*r == reason::VALID) as usize;
                    (*c, *r) = (0.0, reason::NO_ESTIMATE);
                    if invalidate {
                        *d = f32::NAN;
                    }
                }
            }
        }
        Ok(passed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const NAN: f32 = f32::NAN;

    /// The vectorised mask is its definition, pixel for pixel: random disparities (NaN, infinite, negative
    /// zero), confidences (NaN, at the threshold) and reasons, at the default threshold and at 0, over lengths
    /// that leave every vector remainder, and slices of unequal length (the shortest bounds it).
    #[test]
    fn the_mask_is_its_definition() {
        let mut s = 0x9e3779b9u32;
        let mut next = || {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            s
        };
        for n in [0usize, 1, 7, 31, 33, 64, 1000] {
            for min in [0.7f32, 0.0] {
                let d: Vec<f32> = (0..n)
                    .map(|_| match next() % 8 {
                        0 => NAN,
                        1 => f32::INFINITY,
                        2 => -0.0,
                        _ => (next() % 1000) as f32 / 7.0,
                    })
                    .collect();
                let c: Vec<f32> = (0..n + 3)
                    .map(|_| match next() % 6 {
                        0 => NAN,
                        1 => 0.7,
                        _ => (next() % 1001) as f32 / 1000.0,
                    })
                    .collect();
                let y: Vec<u8> = (0..n).map(|_| (next() % 8) as u8).collect();
                let (mut dm, mut ym) = (d.clone(), y.clone());
                mask(&c, min, &mut dm, &mut ym);
                for i in 0..n {
                    let (finite, keep) = (d[i].is_finite(), c[i] >= min);
                    let want_y = match (finite, keep) {
                        (false, _) if y[i] == reason::VALID => reason::NO_ESTIMATE,
                        (false, _) => y[i],
                        (true, true) => reason::VALID,
                        (true, false) => y[i],
                    };
                    let want_d = if finite && !keep && min > 0.0 { NAN } else { d[i] };
                    assert_eq!(ym[i], want_y, "n {n} min {min} at {i}");
                    assert_eq!(dm[i].to_bits(), want_d.to_bits(), "n {n} min {min} at {i}");
                }
            }
        }
    }

    /// The fused copy and mask is the copy, then [`mask`]: random inputs, some pixels not seen, both thresholds.
    #[test]
    fn mask_into_is_a_copy_then_the_mask() {
        let mut s = 0x1234567u32;
        let mut next = || {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            s
        };
        for n in [0usize, 5, 32, 100, 1001] {
            for min in [0.7f32, 0.0] {
                let d: Vec<f32> =
                    (0..n).map(|_| if next() % 5 == 0 { NAN } else { (next() % 1000) as f32 / 9.0 }).collect();
                let c: Vec<f32> =
                    (0..n).map(|_| if next() % 7 == 0 { NAN } else { (next() % 1001) as f32 / 1000.0 }).collect();
                let y: Vec<u8> = (0..n).map(|_| (next() % 8) as u8).collect();
                let seen: Vec<u8> = (0..n).map(|_| (next() % 4 != 0) as u8).collect();
                // the definition: the copy (0 and NO_ESTIMATE where not seen), then the mask
                let (mut wd, mut wc, mut wy) = (d.clone(), vec![0f32; n], vec![0u8; n]);
                for i in 0..n {
                    (wc[i], wy[i]) = if seen[i] == 0 { (0.0, reason::NO_ESTIMATE) } else { (c[i], y[i]) };
                }
                mask(&wc.clone(), min, &mut wd, &mut wy);
                let (mut gd, mut gc, mut gy) = (d.clone(), vec![9f32; n], vec![99u8; n]);
                mask_into(&c, &y, &seen, min, &mut gd, &mut gc, &mut gy);
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&gd), bits(&wd), "n {n} min {min}");
                assert_eq!(bits(&gc), bits(&wc), "n {n} min {min}");
                assert_eq!(gy, wy, "n {n} min {min}");
            }
        }
    }

    #[test]
    fn a_consistent_pair_has_confidence_one() {
        // one row, a constant disparity of 2 px: left pixel x matches right pixel x - 2, which says 2 too
        let mut left = [NAN, NAN, 2.0, 2.0, 2.0, 2.0];
        let right = [2.0, 2.0, 2.0, 2.0, NAN, NAN];
        let mut conf = [9.0; 6];
        let passed = lr_check(&mut left, &right, 6, 1.0, true, &mut conf);
        assert_eq!(passed, 4);
        assert_eq!(conf, [0.0, 0.0, 1.0, 1.0, 1.0, 1.0]);
        assert_eq!(&left[2..], &[2.0; 4]);
        // a disagreement within max_diff is graded: exp(-0.5)
        // (pixel 3 with 2.5 px matches x = round(0.5) = 1)
        let mut left = [NAN, NAN, 2.0, 2.5];
        let right = [2.0, 2.0, 2.0, 2.0];
        let mut conf = [0.0; 4];
        lr_check(&mut left, &right, 4, 1.0, true, &mut conf);
        assert!((conf[3] - (-0.5f32).exp()).abs() < 1e-6, "{conf:?}");
        assert_eq!(conf[2], 1.0);
    }

    #[test]
    fn an_occlusion_gives_zero_and_is_invalidated_only_when_asked() {
        // left pixel 3 says 1 px (matches right pixel 2), but right pixel 2 belongs to a nearer surface (3 px):
        // the left pixel is occluded in the right view
        let right = [3.0, 3.0, 3.0, 1.0, 1.0];
        let mut left = [NAN, 3.0, 3.0, 1.0, 1.0];
        let mut conf = [9.0; 5];
        let passed = lr_check(&mut left, &right, 5, 1.0, false, &mut conf);
        assert_eq!(conf[3], 0.0, "{conf:?}");
        assert_eq!(passed, 1, "{conf:?}");
        assert_eq!(left[3], 1.0, "kept without invalidate");
        let mut conf = [9.0; 5];
        lr_check(&mut left, &right, 5, 1.0, true, &mut conf);
        assert!(left[3].is_nan() && conf[3] == 0.0);
        // a right view without a disparity there fails too
        let mut left = [NAN, 1.0];
        let mut conf = [9.0; 2];
        assert_eq!(lr_check(&mut left, &[NAN, NAN], 2, 1.0, true, &mut conf), 0);
        assert_eq!(conf, [0.0, 0.0]);
    }

    #[test]
    fn a_match_outside_the_right_image_gives_zero() {
        // pixel 1 with 3 px matches x = -2; pixel 3 with 3 px matches x = 0, inside
        let mut left = [0.0, 3.0, NAN, 3.0];
        let right = [3.0, NAN, NAN, NAN];
        let mut conf = [9.0; 4];
        lr_check(&mut left, &right, 4, 1.0, true, &mut conf);
        assert_eq!(conf, [0.0, 0.0, 0.0, 1.0]);
        // pixel 0 with disparity 0 matches right pixel 0 (3 px there: inconsistent)
        assert!(left[0].is_nan() && left[1].is_nan() && left[3] == 3.0);
        // a negative disparity (a match to the right) past the edge, too
        let mut left = [NAN, -1.0];
        let mut conf = [9.0; 2];
        assert_eq!(lr_check(&mut left, &[0.0, 0.0], 2, 1.0, false, &mut conf), 0);
    }

    #[test]
    fn mirroring_reverses_each_row() {
        let mut out = [0u8; 6];
        mirror_rows(&[1, 2, 3, 4, 5, 6], 3, &mut out);
        assert_eq!(out, [3, 2, 1, 6, 5, 4]);
    }

    #[test]
    fn the_right_view_of_a_shifted_pair_agrees_through_a_real_engine() {
        // a random texture, the right image the left shifted by 6 px: SGBM's left-right check passes
        // wherever the left view has a match, and confidence is 0 at the left band without one
        let (w, h, shift) = (96usize, 48usize, 6usize);
        let mut s = 12345u32;
        let mut tex = vec![0u8; (w + shift) * h];
        for t in tex.iter_mut() {
            s = s.wrapping_mul(1664525).wrapping_add(1013904223);
            *t = (s >> 24) as u8;
        }
        // left(x) = tex(x), right(x) = tex(x + shift): left pixel x is right pixel x - shift
        let mut left = vec![0u8; w * h];
        let mut right = vec![0u8; w * h];
        for y in 0..h {
            for x in 0..w {
                left[y * w + x] = tex[y * (w + shift) + x];
                right[y * w + x] = tex[y * (w + shift) + x + shift];
            }
        }
        let mut engine = crate::sgbm::SgbmEngine::new(w as u32, h as u32, 16.0).unwrap();
        let valid = vec![1u8; w * h];
        let (mut disparity, mut confidence) = (vec![f32::NAN; w * h], vec![0f32; w * h]);
        let cfg = CheckConfig { confidence: true, invalidate: true, max_diff: 1.0 };
        let mut check = LrCheck::new(cfg).unwrap();
        check.start(w as u32, h as u32);
        engine.compute(&left, &right, &mut disparity).unwrap();
        check.run(&mut engine, &left, &right, Some(&valid), &mut disparity, Some(&mut confidence), None).unwrap();
        let interior: Vec<usize> = (8..h - 8).flat_map(|y| (24..w - 8).map(move |x| y * w + x)).collect();
        let good = interior.iter().filter(|&&i| confidence[i] > 0.8).count();
        assert!(good as f64 > 0.9 * interior.len() as f64, "{good} of {} confident", interior.len());
        for &i in &interior {
            if confidence[i] > 0.8 {
                assert!((disparity[i] - shift as f32).abs() < 1.0, "pixel {i}: {}", disparity[i]);
            }
        }
        for (c, d) in confidence.iter().zip(&disparity) {
            assert!((0.0..=1.0).contains(c));
            assert_eq!(*c == 0.0, d.is_nan(), "confidence 0 exactly where the disparity was invalidated");
        }
    }
}
