//! The fovea's matching core: disparity at native scale over a window, searched narrowly around a coarser
//! main map's answer and refined against it. The runtime's fovea stage (`abvs-runtime`, which rectifies the
//! window from raw frames) and `abvs disparity-eval --fovea` (a rectified pair at its own scale) both call it.
//!
//! - [`main_histogram`] and [`search_range`]: the search `[start, start + range)` from the main map's
//!   disparities over the window (5th to 95th percentile, scaled to the fovea, widened by two main-map
//!   pixels) or, where the main map has too few there, around a fallback disparity.
//! - [`FoveaMatcher`]: SGBM_3WAY (5x5 blocks) on the window pair. The caller gives the left window with
//!   `max_range` columns more on its left (SGBM answers no pixel in its first `range` columns) and the right
//!   window the same size, its columns shifted by `start` (right column `u` = the right image at the left
//!   image's column `u - start`), so SGBM searches `[0, range)`.
//! - [`refine`]: the main map's answer stands where the narrow search has none, leaves it by more than two
//!   main-map pixels or leaves the depth range; where the main map has no answer (its validity mask) the
//!   fovea has none either.
use crate::engine::DisparityEngine;
use crate::error::Result;
use crate::sgbm::SgbmEngine;

/// Bins per pixel of the histogram of the main map's disparities over the window.
pub const HIST_BINS_PER_PX: f64 = 4.0;
/// Fewer main-map disparities than this fraction of the window's pixels (at the main scale): the search
/// is centred on the fallback disparity instead.
const MIN_MAIN_FRACTION: f64 = 0.05;

/// The histogram of the main map's positive disparities (`HIST_BINS_PER_PX` bins per main-map pixel,
/// `hist` zeroed first) over rows `v0..=v1` and columns `u0..=u1` of a map `width` wide; returns how many.
pub fn main_histogram(
    main: &[f32],
    width: usize,
    (u0, u1): (usize, usize),
    (v0, v1): (usize, usize),
    hist: &mut [u32],
) -> u64 {
    hist.fill(0);
    let mut n = 0u64;
    let last = hist.len() - 1;
    for v in v0..=v1 {
        for &d in &main[v * width + u0..=v * width + u1] {
            if d > 0.0 {
                hist[((d as f64 * HIST_BINS_PER_PX) as usize).min(last)] += 1;
                n += 1;
            }
        }
    }
    n
}

/// The disparity search `(start, range, from_main)` (px at the fovea's scale) from the histogram of `n`
/// main-map disparities over a window of `window_px` main-map pixels, or around `d_fix`. `scale` = fovea
/// focal / main focal, `max_range` the widest search, `lim` = the disparities of the depth range (near,
/// far).
pub fn search_range(
    hist: &[u32],
    n: u64,
    window_px: f64,
    scale: f64,
    d_fix: f64,
    max_range: u32,
    lim: [f64; 2],
) -> (f64, u32, bool) {
    let pct = |q: f64| -> f64 {
        let target = (q * n as f64).ceil().max(1.0) as u64;
        let mut acc = 0u64;
        for (i, &c) in hist.iter().enumerate() {
            acc += c as u64;
            if acc >= target {
                return (i as f64 + 0.5) / HIST_BINS_PER_PX;
            }
        }
        hist.len() as f64 / HIST_BINS_PER_PX
    };
    let max_range = max_range.max(16) / 16 * 16;
    let from_main = n as f64 >= MIN_MAIN_FRACTION * window_px;
    let (mut lo, mut hi, centre) = if from_main {
        // the main map's error is about a pixel of its own: a margin of two of them at the fovea's scale
        let margin = (2.0 * scale).max(4.0);
        (pct(0.05) * scale - margin, pct(0.95) * scale + margin, pct(0.5) * scale)
    } else {
        let half = max_range as f64 / 2.0;
        (d_fix - half, d_fix + half, d_fix)
    };
    lo = lo.max(lim[1] - 1.0);
    hi = hi.min(lim[0] + 1.0).max(lo + 16.0);
    let range = (((hi - lo).ceil() as u32).div_ceil(16) * 16).clamp(16, max_range);
    if hi - lo > range as f64 {
        // wider than the widest search: centred on the median, within the depth range
        lo = (centre - range as f64 / 2.0).max(lim[1] - 1.0);
    }
    (lo.floor(), range, from_main)
}

/// The main map at one fovea pixel (nearest main pixel along the same ray), as [`refine`] reads it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MainAt {
    /// Outside the main map: the fovea's own answer stands.
    Outside,
    /// The main map has no depth there (its validity mask).
    Masked,
    /// The main map's disparity, scaled to the fovea.
    Disparity(f32),
}

/// How often [`refine`] acted (window pixels).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RefineCounts {
    /// The narrow search left no answer: the main map's stands.
    pub filled: u64,
    /// The narrow search's answer left the main map's by more than its error, or the depth range.
    pub overruled: u64,
    /// The main map has no depth there: neither has the fovea.
    pub masked: u64,
}

/// The refinement rule over a window's disparities (fovea scale, NaN = no answer): see the module doc.
/// `valid[i] == 0` marks a pixel outside the source image (left as it is); `scale` = fovea / main focal (the
/// tolerance is two main-map pixels); `lim` = the depth range's disparities (near, far).
pub fn refine(disparity: &mut [f32], valid: &[u8], main: &[MainAt], scale: f64, lim: [f64; 2]) -> RefineCounts {
    let mut c = RefineCounts::default();
    let tol = (2.0 * scale) as f32;
    // a refinement that leaves the depth range (a far wall's few pixels of disparity) keeps the main map's
    let (d_lo, d_hi) = (lim[1] as f32, lim[0] as f32);
    for ((fd, &val), m) in disparity.iter_mut().zip(valid).zip(main) {
        if val == 0 {
            continue;
        }
        match *m {
            MainAt::Outside => {}
            MainAt::Disparity(main) => {
                if !fd.is_finite() {
                    *fd = main;
                    c.filled += 1;
                } else if (*fd - main).abs() > tol || !(d_lo..=d_hi).contains(fd) {
                    *fd = main;
                    c.overruled += 1;
                }
            }
            MainAt::Masked => {
                if fd.is_finite() {
                    *fd = f32::NAN;
                    c.masked += 1;
                }
            }
        }
    }
    c
}

/// SGBM_3WAY over a fovea window (see the module doc).
pub struct FoveaMatcher {
    width: u32,
    height: u32,
    pad: u32,
    sgbm: SgbmEngine,
    ext: Vec<f32>,
}

impl FoveaMatcher {
    /// For a `width` x `height` window and searches up to `max_range` px (the left padding).
    pub fn new(width: u32, height: u32, max_range: u32) -> Result<FoveaMatcher> {
        let ew = width + max_range;
        let sgbm = SgbmEngine::new(ew, height, max_range as f64)?;
        Ok(FoveaMatcher { width, height, pad: max_range, sgbm, ext: vec![f32::NAN; (ew * height) as usize] })
    }

    /// Width of the padded pair [`Self::compute`] takes: the window plus `max_range` columns on its left.
    pub fn ext_width(&self) -> u32 {
        self.width + self.pad
    }

    /// The window's disparities (fovea px, NaN = no match) from the padded pair, the right one shifted by
    /// `start`, searched over `[start, start + range)` (`range` a multiple of 16 up to `max_range`).
    pub fn compute(
        &mut self,
        left_ext: &[u8],
        right_ext: &[u8],
        start: f64,
        range: u32,
        disparity: &mut [f32],
    ) -> Result<()> {
        if self.sgbm.max_disparity() as u32 != range {
            self.sgbm.set_range(range as i32)?;
        }
        self.sgbm.compute(left_ext, right_ext, &mut self.ext)?;
        let (w, ew, pad, off) = (self.width as usize, self.ext_width() as usize, self.pad as usize, start as f32);
        for v in 0..self.height as usize {
            for (d, de) in disparity[v * w..(v + 1) * w].iter_mut().zip(&self.ext[v * ew + pad..(v + 1) * ew]) {
                *d = de + off;
            }
        }
        Ok(())
    }

    /// [`Self::compute`], then [`refine`] against the main map: the fovea of a window.
    #[allow(clippy::too_many_arguments)]
    pub fn fovea(
        &mut self,
        left_ext: &[u8],
        right_ext: &[u8],
        (start, range): (f64, u32),
        valid: &[u8],
        main: &[MainAt],
        scale: f64,
        lim: [f64; 2],
        disparity: &mut [f32],
    ) -> Result<RefineCounts> {
        self.compute(left_ext, right_ext, start, range, disparity)?;
        Ok(refine(disparity, valid, main, scale, lim))
    }
}

/// The padded window pair of a rectified pair at the fovea's scale (`iw` x `ih`, 8-bit gray): the left
/// window at columns `x0..x0 + width`, rows `y0..y0 + height`, with `pad` columns more on its left, and the
/// right one the same columns shifted by `start` (see the module doc); pixels outside the images are 0 (the
/// runtime's remap border). Returns (left, right, valid: 1 where the left window lies inside the image).
#[allow(clippy::too_many_arguments)]
pub fn static_window(
    left: &[u8],
    right: &[u8],
    (iw, ih): (usize, usize),
    (x0, y0): (i64, i64),
    (width, height): (usize, usize),
    pad: usize,
    start: i64,
) -> (Vec<u8>, Vec<u8>, Vec<u8>) {
    let ew = width + pad;
    let (mut l, mut r, mut valid) = (vec![0u8; ew * height], vec![0u8; ew * height], vec![0u8; width * height]);
    let inside = |x: i64, y: i64| x >= 0 && y >= 0 && (x as usize) < iw && (y as usize) < ih;
    for v in 0..height {
        let y = y0 + v as i64;
        for u in 0..ew {
            let x = x0 - pad as i64 + u as i64;
            if inside(x, y) {
                l[v * ew + u] = left[y as usize * iw + x as usize];
                if u >= pad {
                    valid[v * width + u - pad] = 1;
                }
            }
            let xr = x - start;
            if inside(xr, y) {
                r[v * ew + u] = right[y as usize * iw + xr as usize];
            }
        }
    }
    (l, r, valid)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_search_follows_the_main_map_or_else_the_fixation() {
        // main map: disparities 10..12 px at its scale over the window, fovea at 2.5x
        let mut hist = vec![0u32; 4 * 640 + 1];
        for b in 40..48 {
            hist[b] = 100;
        }
        let lim = [400.0, 5.0];
        let (start, range, from_main) = search_range(&hist, 800, 4000.0, 2.5, 80.0, 64, lim);
        assert!(from_main);
        assert!(start <= 25.0 - 5.0 && start + range as f64 >= 30.0 + 5.0, "{start} {range}");
        assert_eq!(range % 16, 0);
        // too few main-map disparities: around the fixation's
        let (start, range, from_main) = search_range(&hist, 100, 40000.0, 2.5, 80.0, 64, lim);
        assert!(!from_main);
        assert_eq!((start, range), (48.0, 64));
        // a spread wider than the widest search: centred on the median
        let mut wide = vec![0u32; 4 * 640 + 1];
        wide[4] = 100;
        wide[400] = 100;
        let (start, range, _) = search_range(&wide, 200, 4000.0, 2.5, 80.0, 64, lim);
        assert_eq!(range, 64);
        assert!((4.0..250.0).contains(&start), "{start}");
    }

    #[test]
    fn the_main_map_fills_overrules_and_masks() {
        let mut d = [f32::NAN, 10.0, 10.0, 30.0, 10.0, 10.0, 10.0];
        let valid = [1, 1, 1, 1, 1, 0, 1];
        let main = [
            MainAt::Disparity(12.0),
            MainAt::Disparity(12.0), // within 2 main px (scale 1.5: 3 px)
            MainAt::Disparity(14.0), // beyond
            MainAt::Disparity(30.0), // beyond the far-near range
            MainAt::Masked,
            MainAt::Masked, // outside the image: left alone
            MainAt::Outside,
        ];
        let c = refine(&mut d, &valid, &main, 1.5, [25.0, 1.0]);
        assert_eq!(c, RefineCounts { filled: 1, overruled: 2, masked: 1 });
        assert_eq!(&d[..4], &[12.0, 10.0, 14.0, 30.0]);
        assert!(d[4].is_nan() && d[5] == 10.0 && d[6] == 10.0);
    }

    #[test]
    fn a_shifted_pair_is_matched_at_its_true_disparity() {
        // a random texture, the right image shifted 37 px: the narrow search [30, 46) finds 37
        let (iw, ih) = (200usize, 60usize);
        let mut s = 12345u32;
        let mut noise = || {
            s = s.wrapping_mul(1103515245).wrapping_add(12345);
            (s >> 16) as u8
        };
        let left: Vec<u8> = (0..iw * ih).map(|_| noise()).collect();
        let mut right = vec![0u8; iw * ih];
        for y in 0..ih {
            for x in 0..iw - 37 {
                right[y * iw + x] = left[y * iw + x + 37];
            }
        }
        let (w, h, pad) = (64usize, 32usize, 32u32);
        let (l, r, valid) = static_window(&left, &right, (iw, ih), (100, 14), (w, h), pad as usize, 30);
        assert!(valid.iter().all(|v| *v == 1));
        let mut m = FoveaMatcher::new(w as u32, h as u32, pad).unwrap();
        let mut d = vec![0f32; w * h];
        m.compute(&l, &r, 30.0, 16, &mut d).unwrap();
        let good = d.iter().filter(|v| (**v - 37.0).abs() <= 0.5).count();
        assert!(good as f64 > 0.9 * (w * h) as f64, "{good} of {}", w * h);
    }
}
