//! Corners of the left image and their sub-pixel matches in the right one (band search, Lucas-Kanade).
use super::*;

/// One sub-pixel match between the rectified images (px).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Match {
    /// Left image, x.
    pub xl: f32,
    /// Left image, y.
    pub yl: f32,
    /// Right image, x.
    pub xr: f32,
    /// Right image, y.
    pub yr: f32,
    /// Normalised cross-correlation of the refined patches.
    pub ncc: f32,
}

impl Match {
    /// Vertical disparity v_r - v_l (px).
    pub fn dy(&self) -> f32 {
        self.yr - self.yl
    }
}

/// Sparse band matcher: corners of the left image (Shi-Tomasi, one per grid cell), each searched for in the
/// right image over the band of rows and the disparity range (zero-mean SAD, distinctive best), then refined
/// by Lucas-Kanade ([`refine`]). Plain Rust on the calling thread: OpenCV's feature detectors would run on its
/// process-wide thread pool (TBB), the same workers as the pipeline's remap and SGBM.
pub struct Matcher {
    band_px: f32,
    features: usize,
    /// Scratch: gradient products and their window sums, corner response, integral image of the right image.
    gxx: Vec<f32>,
    gxy: Vec<f32>,
    gyy: Vec<f32>,
    tmp: Vec<f32>,
    resp: Vec<f32>,
    integral: Vec<u32>,
    corners: Vec<(f32, u32, u32)>,
    cands: Vec<(i32, i32, i32)>,
    /// Scratch: the pair box-filtered down to [`MATCH_WIDTH_MAX`] (see [`Matcher::find`]).
    small: [Vec<u8>; 2],
}

/// Widest image matched as it is. The windows (7 x 7 search, 13 x 13 Lucas-Kanade, 5 x 5 tensor), the corner
/// and texture floors and the row band are sized in pixels of a ~320 px wide image: at 640 x 480 the same
/// windows see a quarter of the texture, half the corners pass, and the fit about the vertical axis (toe-in,
/// the weakest) read the fixture's calibrated poses up to 0.11 deg off (true error under 0.01 deg), a
/// pose-dependent bias that the offline report took for an FK error. Wider pairs are box-filtered by 2 until
/// they fit, and the matches scaled back.
pub const MATCH_WIDTH_MAX: usize = 480;

/// Half-size of the matching patch (px) and of the structure tensor's window.
pub(super) const MATCH_R: i32 = 3;
pub(super) const TENSOR_R: usize = 2;
pub(super) const PATCH_R: i32 = 6;

impl Matcher {
    /// At most `features` corners per frame, searched over +-`band_px` rows.
    pub fn new(features: usize, band_px: f32) -> Result<Matcher> {
        Ok(Matcher {
            band_px,
            features,
            gxx: Vec::new(),
            gxy: Vec::new(),
            gyy: Vec::new(),
            tmp: Vec::new(),
            resp: Vec::new(),
            integral: Vec::new(),
            corners: Vec::new(),
            cands: Vec::new(),
            small: [Vec::new(), Vec::new()],
        })
    }

    /// Shi-Tomasi response (smaller eigenvalue of the structure tensor over a 5 x 5 window, per pixel) of
    /// `img`; 0 where the window touches an unseen (black) pixel.
    pub(super) fn response(&mut self, img: &[u8], w: usize, h: usize) {
        let n = w * h;
        for v in [&mut self.gxx, &mut self.gxy, &mut self.gyy, &mut self.tmp, &mut self.resp] {
            v.clear();
            v.resize(n, 0.0);
        }
        for y in 1..h - 1 {
            for x in 1..w - 1 {
                let i = y * w + x;
                let gx = 0.5 * (img[i + 1] as f32 - img[i - 1] as f32);
                let gy = 0.5 * (img[i + w] as f32 - img[i - w] as f32);
                let dark = img[i] == 0 || img[i + 1] == 0 || img[i - 1] == 0 || img[i + w] == 0 || img[i - w] == 0;
                // an unseen pixel poisons its window (NaN propagates through the sums)
                let k = if dark { f32::NAN } else { 1.0 };
                self.gxx[i] = gx * gx * k;
                self.gxy[i] = gx * gy * k;
                self.gyy[i] = gy * gy * k;
            }
        }
        let r = TENSOR_R;
        let tmp = &mut self.tmp;
        for g in [&mut self.gxx, &mut self.gxy, &mut self.gyy] {
            // separable box sums, rows then columns
            for y in 0..h {
                for x in r..w - r {
                    tmp[y * w + x] = (x - r..=x + r).map(|k| g[y * w + k]).sum();
                }
            }
            g.iter_mut().for_each(|v| *v = 0.0);
            for y in r..h - r {
                for x in r..w - r {
                    g[y * w + x] = (y - r..=y + r).map(|k| tmp[k * w + x]).sum();
                }
            }
        }
        for i in 0..n {
            let (a, b, c) = (self.gxx[i], self.gxy[i], self.gyy[i]);
            let l = 0.5 * (a + c) - (0.25 * (a - c) * (a - c) + b * b).sqrt();
            self.resp[i] = if l.is_finite() { l } else { 0.0 };
        }
    }

    /// Matches of the rectified pair `left`, `right` (`w` x `h`, 8-bit) with horizontal disparity in
    /// [-1, `max_disp`] px, refined to sub-pixel precision; `out` is cleared first. A pair wider than
    /// [`MATCH_WIDTH_MAX`] is matched box-filtered by 2 (repeatedly) and its matches given in `w` x `h` pixels.
    pub fn find(
        &mut self,
        left: &[u8],
        right: &[u8],
        w: usize,
        h: usize,
        max_disp: f32,
        out: &mut Vec<Match>,
    ) -> Result<()> {
        if left.len() != w * h || right.len() != w * h {
            return Err(RuntimeError::Invalid(format!("self-check: images are not {w}x{h}")));
        }
        let mut level = 0;
        while (w >> level) > MATCH_WIDTH_MAX && (h >> (level + 1)) >= 1 {
            level += 1;
        }
        if level == 0 {
            return self.find_native(left, right, w, h, max_disp, out);
        }
        let s = 1usize << level;
        let (sw, sh) = (w / s, h / s);
        let mut small = std::mem::take(&mut self.small);
        shrink(left, w, s, sw, sh, &mut small[0]);
        shrink(right, w, s, sw, sh, &mut small[1]);
        let r = self.find_native(&small[0], &small[1], sw, sh, max_disp / s as f32, out);
        self.small = small;
        r?;
        // the centre of a small pixel i is the mean of its source pixels s i .. s i + s - 1
        let (k, c) = (s as f32, 0.5 * (s as f32 - 1.0));
        for m in out.iter_mut() {
            (m.xl, m.yl, m.xr, m.yr) = (k * m.xl + c, k * m.yl + c, k * m.xr + c, k * m.yr + c);
        }
        Ok(())
    }

    fn find_native(
        &mut self,
        left: &[u8],
        right: &[u8],
        w: usize,
        h: usize,
        max_disp: f32,
        out: &mut Vec<Match>,
    ) -> Result<()> {
        out.clear();
        if left.len() != w * h || right.len() != w * h {
            return Err(RuntimeError::Invalid(format!("self-check: images are not {w}x{h}")));
        }
        let margin = (PATCH_R + 2) as usize;
        if w < 4 * margin || h < 4 * margin {
            return Ok(());
        }
        // corners of the left image: the strongest local maximum of each grid cell, over a floor
        self.response(left, w, h);
        self.corners.clear();
        let floor = 6.0 * ((2 * TENSOR_R + 1) * (2 * TENSOR_R + 1)) as f32; // gradients of ~2.5 grey levels
                                                                            // one corner per cell, cells sized so that they number about `features`: spread over the image
        let cell = (((w * h) as f64 / self.features.max(1) as f64).sqrt() as usize).max(6);
        for cy in (margin..h - margin).step_by(cell) {
            for cx in (margin..w - margin).step_by(cell) {
                let mut best = (floor, 0, 0);
                for y in cy..(cy + cell).min(h - margin) {
                    for x in cx..(cx + cell).min(w - margin) {
                        let v = self.resp[y * w + x];
                        if v > best.0 {
                            best = (v, x, y);
                        }
                    }
                }
                if best.0 > floor {
                    let (v, x, y) = best;
                    let local_max = (y - 1..=y + 1)
                        .all(|yy| (x - 1..=x + 1).all(|xx| (xx == x && yy == y) || self.resp[yy * w + xx] <= v));
                    if local_max {
                        self.corners.push((v, x as u32, y as u32));
                    }
                }
            }
        }
        if self.corners.len() > self.features {
            self.corners.sort_by(|a, b| b.0.total_cmp(&a.0));
            self.corners.truncate(self.features);
        }
        // integral image of the right image (patch means in O(1))
        let iw = w + 1;
        self.integral.clear();
        self.integral.resize(iw * (h + 1), 0);
        for y in 0..h {
            let mut row = 0u32;
            for x in 0..w {
                row += right[y * w + x] as u32;
                self.integral[(y + 1) * iw + x + 1] = self.integral[y * iw + x + 1] + row;
            }
        }
        let integral = &self.integral;
        let r = MATCH_R;
        let np = (2 * r + 1) * (2 * r + 1);
        let box_sum = |x: i32, y: i32| -> i32 {
            let (x0, y0, x1, y1) = ((x - r) as usize, (y - r) as usize, (x + r + 1) as usize, (y + r + 1) as usize);
            (integral[y1 * iw + x1] + integral[y0 * iw + x0]) as i32
                - (integral[y0 * iw + x1] + integral[y1 * iw + x0]) as i32
        };
        let band = self.band_px.ceil() as i32;
        let max_d = max_disp.ceil() as i32;
        let mut tpl = [0i32; ((2 * MATCH_R + 1) * (2 * MATCH_R + 1)) as usize];
        for &(_, xl, yl) in &self.corners {
            let (xl, yl) = (xl as i32, yl as i32);
            // zero-mean template, scaled by the patch size to stay in integers
            let mut sum = 0;
            let mut k = 0;
            for j in -r..=r {
                for i in -r..=r {
                    let v = left[((yl + j) as usize) * w + (xl + i) as usize] as i32;
                    tpl[k] = v * np;
                    sum += v;
                    k += 1;
                }
            }
            tpl.iter_mut().for_each(|t| *t -= sum);
            // zero-mean SAD of the template at (x, y) of the right image; stops once it reaches `limit`
            let cost = |x: i32, y: i32, limit: i32| -> i32 {
                let mean = box_sum(x, y);
                let mut c = 0;
                let mut k = 0;
                for j in -r..=r {
                    let row = &right[((y + j) as usize) * w..];
                    for i in -r..=r {
                        c += (row[(x + i) as usize] as i32 * np - mean - tpl[k]).abs();
                        k += 1;
                    }
                    if c >= limit {
                        break;
                    }
                }
                c
            };
            let inside = |x: i32, y: i32| x - r >= 0 && x + r < w as i32 && y - r >= 0 && y + r < h as i32;
            // coarse: every other row of the band (a 7 px patch still responds one row off), every disparity;
            // a cost is computed only up to 1.25 x the best so far (past it the candidate is clearly worse)
            self.cands.clear();
            let mut best = (i32::MAX, 0, 0);
            for dy in (-(band / 2)..=band / 2).map(|k| 2 * k) {
                for d in -1..=max_d {
                    let (x, y) = (xl - d, yl + dy);
                    if !inside(x, y) {
                        continue;
                    }
                    let c = cost(x, y, best.0.saturating_add(best.0 / 4));
                    self.cands.push((c, x, y));
                    if c < best.0 {
                        best = (c, x, y);
                    }
                }
            }
            let (c0, bx, by) = best;
            if c0 == i32::MAX {
                continue;
            }
            // distinctive: every candidate away from the best costs clearly more
            let away = self.cands.iter().filter(|c| (c.1 - bx).abs() > 1 || (c.2 - by).abs() > 2).map(|c| c.0).min();
            if away.is_some_and(|c2| c0 as f32 > 0.8 * c2 as f32) {
                continue;
            }
            // fine: the best integer position around it
            let (cx, cy) = (bx, by);
            let (mut bx, mut by, mut bc) = (bx, by, c0);
            for (i, j) in [(-1, -1), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)] {
                let (x, y) = (cx + i, cy + j);
                if inside(x, y) {
                    let c = cost(x, y, bc);
                    if c < bc {
                        (bx, by, bc) = (x, y, c);
                    }
                }
            }
            if let Some(m) = refine(left, right, w, h, (xl, yl), (bx as f32, by as f32)) {
                out.push(m);
            }
        }
        Ok(())
    }
}

/// `img` (`w` wide) box-filtered by `s` into `out` (`sw` x `sh`); a block touching an unseen (black) pixel
/// stays unseen. `out` is sized on the first frame and reused.
fn shrink(img: &[u8], w: usize, s: usize, sw: usize, sh: usize, out: &mut Vec<u8>) {
    out.resize(sw * sh, 0);
    let n = (s * s) as u32;
    for y in 0..sh {
        for x in 0..sw {
            let (mut sum, mut dark) = (0u32, false);
            for j in 0..s {
                for &v in &img[(s * y + j) * w + s * x..][..s] {
                    sum += v as u32;
                    dark |= v == 0;
                }
            }
            out[y * sw + x] = if dark { 0 } else { ((sum + n / 2) / n).max(1) as u8 };
        }
    }
}

/// Bilinear sample; `None` outside the image or next to a black (unseen) pixel.
#[inline]
pub(super) fn sample(img: &[u8], w: usize, h: usize, x: f32, y: f32) -> Option<f32> {
    if !(x >= 0.0 && y >= 0.0 && x < (w - 1) as f32 && y < (h - 1) as f32) {
        return None;
    }
    let (x0, y0) = (x as usize, y as usize);
    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
    let i = y0 * w + x0;
    let (a, b, c, d) = (img[i], img[i + 1], img[i + w], img[i + w + 1]);
    if a == 0 || b == 0 || c == 0 || d == 0 {
        return None;
    }
    let top = a as f32 + fx * (b as f32 - a as f32);
    let bot = c as f32 + fx * (d as f32 - c as f32);
    Some(top + fy * (bot - top))
}

/// Lucas-Kanade (inverse compositional) of the left patch around the pixel `pl` in the right image, starting
/// at `init`: a vertical shift, and a horizontal shift that may vary linearly across the patch (a slanted
/// surface: x' = x + px + a i + b j, y' = y + py), plus an intensity offset. The match at the patch centre,
/// or `None` when it does not converge, drifts more than 2.5 px, sees unseen (black) pixels, lacks texture or
/// correlates below 0.9.
pub fn refine(left: &[u8], right: &[u8], w: usize, h: usize, pl: (i32, i32), init: (f32, f32)) -> Option<Match> {
    type V5 = nalgebra::SVector<f64, 5>;
    const N: usize = ((2 * PATCH_R + 1) * (2 * PATCH_R + 1)) as usize;
    let (xl, yl) = pl;
    if xl - PATCH_R - 1 < 0 || yl - PATCH_R - 1 < 0 || xl + PATCH_R + 1 >= w as i32 || yl + PATCH_R + 1 >= h as i32 {
        return None;
    }
    let mut t = [0f32; N];
    let mut sd = [V5::zeros(); N];
    let mut hm = nalgebra::SMatrix::<f64, 5, 5>::zeros();
    let mut k = 0;
    for j in -PATCH_R..=PATCH_R {
        for i in -PATCH_R..=PATCH_R {
            let at = |di: i32, dj: i32| left[((yl + j + dj) as usize) * w + (xl + i + di) as usize];
            if at(0, 0) == 0 || at(1, 0) == 0 || at(-1, 0) == 0 || at(0, 1) == 0 || at(0, -1) == 0 {
                return None;
            }
            t[k] = at(0, 0) as f32;
            let gx = 0.5 * (at(1, 0) as f64 - at(-1, 0) as f64);
            let gy = 0.5 * (at(0, 1) as f64 - at(0, -1) as f64);
            sd[k] = V5::new(gx, gy, gx * i as f64, gx * j as f64, 1.0);
            hm += sd[k] * sd[k].transpose();
            k += 1;
        }
    }
    // texture: the smaller eigenvalue of the gradients' covariance (offset removed) per pixel
    let n = N as f64;
    let (sxx, sxy, syy) = (
        hm[(0, 0)] - hm[(0, 4)] * hm[(0, 4)] / n,
        hm[(0, 1)] - hm[(0, 4)] * hm[(1, 4)] / n,
        hm[(1, 1)] - hm[(1, 4)] * hm[(1, 4)] / n,
    );
    let lmin = 0.5 * (sxx + syy - ((sxx - syy).powi(2) + 4.0 * sxy * sxy).sqrt());
    if lmin / n < 4.0 {
        return None;
    }
    let hinv = hm.try_inverse()?;
    // the warp as a homogeneous matrix on patch offsets (i, j, 1)
    let mut warp =
        Matrix3::new(1.0, 0.0, (init.0 - xl as f32) as f64, 0.0, 1.0, (init.1 - yl as f32) as f64, 0.0, 0.0, 1.0);
    let start = (warp[(0, 2)], warp[(1, 2)]);
    let mut cur = [0f32; N];
    let mut converged = false;
    let sample_warped = |warp: &Matrix3<f64>, cur: &mut [f32; N]| -> Option<()> {
        let mut k = 0;
        for j in -PATCH_R..=PATCH_R {
            for i in -PATCH_R..=PATCH_R {
                let x = warp[(0, 0)] * i as f64 + warp[(0, 1)] * j as f64 + warp[(0, 2)];
                let y = j as f64 + warp[(1, 2)];
                cur[k] = sample(right, w, h, (xl as f64 + x) as f32, (yl as f64 + y) as f32)?;
                k += 1;
            }
        }
        Some(())
    };
    for _ in 0..30 {
        sample_warped(&warp, &mut cur)?;
        let mut b = V5::zeros();
        for k in 0..N {
            b += sd[k] * (cur[k] - t[k]) as f64;
        }
        let d = hinv * b;
        let step = Matrix3::new(1.0 + d[2], d[3], d[0], 0.0, 1.0, d[1], 0.0, 0.0, 1.0);
        warp *= step.try_inverse()?;
        if (warp[(0, 2)] - start.0).hypot(warp[(1, 2)] - start.1) > 2.5
            || (warp[(0, 0)] - 1.0).abs() > 0.5
            || warp[(0, 1)].abs() > 0.5
        {
            return None;
        }
        let moved = d[0].hypot(d[1]) + PATCH_R as f64 * (d[2].abs() + d[3].abs());
        if moved < 1e-3 {
            converged = true;
            break;
        }
    }
    if !converged {
        return None;
    }
    sample_warped(&warp, &mut cur)?;
    let ncc = ncc(&t, &cur);
    if ncc < 0.9 {
        return None;
    }
    Some(Match {
        xl: xl as f32,
        yl: yl as f32,
        xr: (xl as f64 + warp[(0, 2)]) as f32,
        yr: (yl as f64 + warp[(1, 2)]) as f32,
        ncc,
    })
}

pub(super) fn ncc(a: &[f32], b: &[f32]) -> f32 {
    let n = a.len() as f32;
    let (ma, mb) = (a.iter().sum::<f32>() / n, b.iter().sum::<f32>() / n);
    let (mut sab, mut saa, mut sbb) = (0f32, 0f32, 0f32);
    for (x, y) in a.iter().zip(b) {
        let (x, y) = (x - ma, y - mb);
        sab += x * y;
        saa += x * x;
        sbb += y * y;
    }
    if saa <= 0.0 || sbb <= 0.0 {
        0.0
    } else {
        sab / (saa * sbb).sqrt()
    }
}
