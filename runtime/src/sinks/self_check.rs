//! Self-check of the stereo calibration from the images (issue 16), off the critical path.
//!
//! A correctly rectified pair has no vertical disparity: a scene point lies on the same row in both images.
//! The sink hands every `every`-th rectified pair to a worker thread of its own (idle CPU time only; when it is
//! still busy the pair is skipped, counted), which
//! 1. picks corners of the left image (Shi-Tomasi, the strongest per cell of a grid of about `features` cells)
//!    and finds each in the right image by a search over a band of rows (`band_px`) and the disparity range
//!    (zero-mean SAD on 7 x 7 patches; the best must beat any runner-up away from it by 20 %). Plain Rust on
//!    the worker: OpenCV's detectors (ORB, FAST) parallelise on OpenCV's process-wide TBB pool, the workers
//!    of the pipeline's remap and SGBM, and so delayed the critical path (measured: +45 % end-to-end p50),
//! 2. refines each match to sub-pixel precision with Lucas-Kanade on a 13 x 13 patch (vertical shift,
//!    horizontal shift varying linearly across the patch as on a slanted surface, intensity offset;
//!    normalised cross-correlation at least 0.9),
//! 3. fits the relative rotation error by robust least squares (IRLS, Huber) to the vertical disparities.
//!
//! **The model.** In the rectified frame (pinhole `f`, `cx`, `cy`, x along the baseline, y down), let the
//! right camera's true orientation differ from the one the rectification used by a small rotation `phi`:
//! a right-camera ray is taken for the direction `d` when it really is `(I + [phi]x) d`, so a point whose
//! ideal right image direction is `d = (x, y, 1)` (normalised) is imaged at `(I - [phi]x) d`. To first order
//! its normalised image position moves by
//!
//! ```text
//! dx = -phi_y (1 + x^2) + phi_z y + phi_x x y
//! dy =  phi_x (1 + y^2) - phi_y x y - phi_z x
//! ```
//! and the left image is unaffected, so the vertical disparity is `v_r - v_l = f (phi_x (1 + y^2) -
//! phi_y x_r y - phi_z x_r)` with `x_r = (u_r - cx) / f`, `y = (v - cy) / f` (translation errors add
//! `f t_y / Z`, which depends on depth and is left out). Horizontal shifts are indistinguishable from depth.
//!
//! **The convention.** The error is reported in the left home camera frame as the small-angle vector `w`
//! with `R_cal = R_true exp([w]x)` for the home extrinsic `T_lH^rH` (x_rH = R x_lH + t): the extrinsic in use is
//! the true one after first rotating the left home frame by `w`. Through the moving extrinsic (`R_l^r =
//! R_rel,r^T R_lH^rH R_rel,l`) this is `R_l^r,cal = R_l^r,true exp([R_rel,l^T w]x)`, so a rectified pixel of
//! the right image is the true one rotated by `-phi` with `phi = rect_from_left R_rel,l^T w`: each frame's
//! design row is `f g^T M` with `g = (1 + y^2, -x_r y, -x_r)` and `M = rect_from_left R_rel,l^T`. Every
//! per-frame relative rotation error (either eye's FK, the home extrinsic) shows up in `w`; the eyes' motion
//! turns `M` from frame to frame, which is what the log's link angles are for.
//!
//! **Statistics.** Per checked frame: matches, |vertical disparity| p50 / p95 (px), `w` and its 1-sigma
//! (from the IRLS residual scale). Over the run: |vertical| quantiles of all matches (0.005 px bins),
//! `w` as the information-weighted mean of the last [`KEEP`] checked frames' estimates (a Huber weight per frame on its distance
//! to the mean), and its sigma from the scatter between frames (cluster-robust sandwich), which includes the
//! frame-to-frame FK error. A warning is printed (once, until it falls back) when the component-wise median
//! of `w` over the last `warn_frames` checked frames exceeds `threshold_deg`.
//!
//! **Limits.** Rotation about the rectified vertical axis (toe-in) moves features mostly horizontally, which
//! is indistinguishable from depth; its vertical signature (`x_r y`) is weak, so per frame that component is
//! the least certain (on the fixture, per frame against the truth: x within 0.003 deg, z 0.005, y 0.01). The
//! corners matter: ORB keypoints (clustered on object corners and depth edges) read single fixations up to
//! 0.2 deg off about y.
use std::io::Write;
use std::path::PathBuf;
use std::thread::JoinHandle;

use crossbeam_channel::{bounded, Receiver, Sender};
use nalgebra::{Matrix3, Vector3};
use serde_json::{json, Value};

use crate::error::{Result, RuntimeError};
use crate::pipeline::{Published, Sink};
use crate::sinks::stats::{Latency, RunStats};
use crate::tasks::rectify::RectifiedCamera;

/// How the self-check runs.
#[derive(Debug, Clone, PartialEq)]
pub struct SelfCheckConfig {
    /// Check every n-th frame (by `seq`; 1 = every frame). 5 by default: 5 checks a second at 25 fps, a
    /// fifth of the worker's CPU time (10 ms a check at 320x240, release) for the same drift detection.
    pub every: u64,
    /// Half-height of the band of rows searched for a match (px).
    pub band_px: f32,
    /// Nearest depth matched (m): the disparity range is f B / min_depth.
    pub min_depth_m: f64,
    /// Corners searched per frame (at most).
    pub features: usize,
    /// Warn when the rotation error (median of the last `warn_frames` checked frames) exceeds this (deg).
    pub threshold_deg: f64,
    /// Window of the warning (checked frames).
    pub warn_frames: u32,
    /// Per-frame CSV log.
    pub log: Option<PathBuf>,
    /// Wait for the worker instead of skipping frames (offline, reproducible; costs the output stage the wait).
    pub blocking: bool,
    /// Run the worker only on otherwise idle CPU time (Linux SCHED_IDLE; nice 19 where refused), so it never
    /// takes a core from the pipeline's stages; false keeps the pipeline's priority.
    pub background: bool,
}

impl Default for SelfCheckConfig {
    fn default() -> Self {
        SelfCheckConfig {
            every: 5,
            band_px: 4.0,
            min_depth_m: 0.15,
            features: 300,
            threshold_deg: 0.1,
            warn_frames: 25,
            log: None,
            blocking: false,
            background: true,
        }
    }
}

/// One sub-pixel match between the rectified images (px).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Match {
    pub xl: f32,
    pub yl: f32,
    pub xr: f32,
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
}

/// Half-size of the matching patch (px) and of the structure tensor's window.
const MATCH_R: i32 = 3;
const TENSOR_R: usize = 2;
const PATCH_R: i32 = 6;

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
        })
    }

    /// Shi-Tomasi response (smaller eigenvalue of the structure tensor over a 5 x 5 window, per pixel) of
    /// `img`; 0 where the window touches an unseen (black) pixel.
    fn response(&mut self, img: &[u8], w: usize, h: usize) {
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
    /// [-1, `max_disp`] px, refined to sub-pixel precision; `out` is cleared first.
    pub fn find(
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

/// Bilinear sample; `None` outside the image or next to a black (unseen) pixel.
#[inline]
fn sample(img: &[u8], w: usize, h: usize, x: f32, y: f32) -> Option<f32> {
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

fn ncc(a: &[f32], b: &[f32]) -> f32 {
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

/// A rotation error fitted to one frame's vertical disparities.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RotationFit {
    /// The error `w` (rad) in the left home camera frame (module docs).
    pub omega: Vector3<f64>,
    /// Information matrix J^T W J / s^2 (1/rad^2).
    pub info: Matrix3<f64>,
    /// 1-sigma of each component (rad).
    pub sigma: Vector3<f64>,
    /// Robust residual scale (px).
    pub scale_px: f64,
    /// Matches with full weight.
    pub inliers: usize,
}

/// The design row of one match: d(dy)/d(w) in px/rad for `m` = rect_from_left R_rel,l^T.
pub fn design_row(m: &Match, cam: &RectifiedCamera, rot: &Matrix3<f64>) -> Vector3<f64> {
    let xr = (m.xr as f64 - cam.cx) / cam.f;
    let y = (0.5 * (m.yl + m.yr) as f64 - cam.cy) / cam.f;
    let g = Vector3::new(1.0 + y * y, -xr * y, -xr);
    rot.transpose() * g * cam.f
}

/// Fits the rotation error `w` (left home frame) to the vertical disparities by IRLS with Huber weights
/// (k = 1.345 robust sigmas); `rot` = rect_from_left R_rel,l^T. `None` with fewer than 12 matches or a
/// singular design.
pub fn fit_rotation(matches: &[Match], cam: &RectifiedCamera, rot: &Matrix3<f64>) -> Option<RotationFit> {
    if matches.len() < 12 {
        return None;
    }
    let rows: Vec<(Vector3<f64>, f64)> = matches.iter().map(|m| (design_row(m, cam, rot), m.dy() as f64)).collect();
    let mut wts = vec![1.0; rows.len()];
    let mut omega = Vector3::zeros();
    let mut scale = 1.0;
    let mut res: Vec<f64> = vec![0.0; rows.len()];
    for it in 0..20 {
        let mut a = Matrix3::zeros();
        let mut b = Vector3::zeros();
        for ((j, y), wt) in rows.iter().zip(&wts) {
            a += *j * j.transpose() * *wt;
            b += *j * (*y * *wt);
        }
        let next = a.try_inverse()? * b;
        for (r, (j, y)) in res.iter_mut().zip(&rows) {
            *r = y - j.dot(&next);
        }
        let mut abs: Vec<f64> = res.iter().map(|r| r.abs()).collect();
        abs.sort_by(f64::total_cmp);
        // MAD about zero residual (the fit removes the median's structure); floor for exact data
        scale = (1.4826 * abs[abs.len() / 2]).max(1e-3);
        let k = 1.345 * scale;
        for (wt, r) in wts.iter_mut().zip(&res) {
            *wt = if r.abs() <= k { 1.0 } else { k / r.abs() };
        }
        let step = (next - omega).norm();
        omega = next;
        if it > 0 && step < 1e-9 {
            break;
        }
    }
    let mut a = Matrix3::zeros();
    for ((j, _), wt) in rows.iter().zip(&wts) {
        a += *j * j.transpose() * *wt;
    }
    let info = a / (scale * scale);
    let cov = info.try_inverse()?;
    let inliers = wts.iter().filter(|w| **w >= 1.0).count();
    Some(RotationFit {
        omega,
        info,
        sigma: Vector3::new(cov[(0, 0)].sqrt(), cov[(1, 1)].sqrt(), cov[(2, 2)].sqrt()),
        scale_px: scale,
        inliers,
    })
}

/// What one checked frame measured.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameCheck {
    pub seq: u64,
    pub t_frame_ns: i64,
    /// Both eyes' link angles (deg).
    pub theta: [[f64; 3]; 2],
    pub matches: usize,
    /// |vertical disparity| quantiles (px); NaN without matches.
    pub vertical_p50: f64,
    pub vertical_p95: f64,
    pub fit: Option<RotationFit>,
}

/// Quantile of sorted values (nearest rank); NaN when empty.
fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() as f64 * q).ceil() as usize).clamp(1, sorted.len()) - 1]
}

/// The matrix `M` = rect_from_left R_rel,l^T of a published frame.
pub fn frame_rotation(out: &Published) -> Matrix3<f64> {
    out.rect.rect_from_left * out.pose.rel_left.r.transpose()
}

/// Checks one rectified pair: matches, vertical statistics and the rotation fit.
pub fn check_frame(matcher: &mut Matcher, job: &Job, matches: &mut Vec<Match>) -> Result<FrameCheck> {
    let (w, h) = (job.cam.width as usize, job.cam.height as usize);
    matcher.find(&job.left, &job.right, w, h, job.max_disp, matches)?;
    let mut abs: Vec<f64> = matches.iter().map(|m| m.dy().abs() as f64).collect();
    abs.sort_by(f64::total_cmp);
    Ok(FrameCheck {
        seq: job.seq,
        t_frame_ns: job.t_frame_ns,
        theta: job.theta,
        matches: matches.len(),
        vertical_p50: quantile(&abs, 0.5),
        vertical_p95: quantile(&abs, 0.95),
        fit: fit_rotation(matches, &job.cam, &job.rot),
    })
}

/// One rectified pair handed to the worker (pooled: allocated at start-up).
pub struct Job {
    pub seq: u64,
    pub t_frame_ns: i64,
    pub theta: [[f64; 3]; 2],
    /// rect_from_left R_rel,l^T.
    pub rot: Matrix3<f64>,
    pub cam: RectifiedCamera,
    pub max_disp: f32,
    pub left: Vec<u8>,
    pub right: Vec<u8>,
}

const BIN_PX: f64 = 0.005;
/// Checked frames kept for the run's rotation estimate and match count (about 33 minutes at 5 a second).
pub const KEEP: usize = 10_000;
const BINS: usize = 4000;

/// The run's self-check: everything the worker accumulated.
pub struct Summary {
    pub frames: u64,
    /// Checked frames whose matches did not support a rotation fit.
    pub frames_unfitted: u64,
    /// Frames the worker was too busy for.
    pub skipped: u64,
    pub warnings: u64,
    /// Matches of the last [`KEEP`] checked frames.
    matches: std::collections::VecDeque<u32>,
    /// |vertical disparity| histogram of all matches (BIN_PX bins, the last one open).
    vertical: Vec<u64>,
    /// Rotation fits of the last [`KEEP`] checked frames (the run's estimate is theirs: memory stays bounded).
    fits: std::collections::VecDeque<(Vector3<f64>, Matrix3<f64>)>,
    /// Time the worker spent on each checked frame.
    pub check_time: Latency,
    /// CPU time of the worker thread on each checked frame (what the check costs the machine).
    pub check_cpu: Latency,
    /// The last `warn_frames` frames' rotation errors.
    recent: std::collections::VecDeque<Vector3<f64>>,
    warned: bool,
    failed: u64,
}

impl Default for Summary {
    fn default() -> Self {
        Summary {
            frames: 0,
            frames_unfitted: 0,
            skipped: 0,
            warnings: 0,
            matches: std::collections::VecDeque::new(),
            vertical: vec![0; BINS],
            fits: std::collections::VecDeque::new(),
            check_time: Latency::default(),
            check_cpu: Latency::default(),
            recent: std::collections::VecDeque::new(),
            warned: false,
            failed: 0,
        }
    }
}

impl Summary {
    fn add(&mut self, c: &FrameCheck, ms: &[Match], cfg: &SelfCheckConfig) {
        self.frames += 1;
        if self.matches.len() == KEEP {
            self.matches.pop_front();
        }
        self.matches.push_back(c.matches as u32);
        for m in ms {
            let b = ((m.dy().abs() as f64 / BIN_PX) as usize).min(BINS - 1);
            self.vertical[b] += 1;
        }
        match &c.fit {
            Some(f) => {
                if self.fits.len() == KEEP {
                    self.fits.pop_front();
                }
                self.fits.push_back((f.omega, f.info));
                let n = cfg.warn_frames.max(1) as usize;
                if self.recent.len() == n {
                    self.recent.pop_front();
                }
                self.recent.push_back(f.omega);
                if self.recent.len() == n {
                    // component-wise median of the window: a persistent error, not one odd frame
                    let med = |k: usize| {
                        let mut v: Vec<f64> = self.recent.iter().map(|w| w[k]).collect();
                        v.sort_by(f64::total_cmp);
                        0.5 * (v[(n - 1) / 2] + v[n / 2])
                    };
                    let m = Vector3::new(med(0), med(1), med(2)).map(f64::to_degrees);
                    if m.norm() > cfg.threshold_deg {
                        if !self.warned {
                            self.warned = true;
                            self.warnings += 1;
                            eprintln!(
                                "warning: self-check: stereo rotation error [{:.3}, {:.3}, {:.3}] deg (median of the \
                                 last {n} checked frames, up to frame {}; |vertical| p50 {:.2} px) exceeds {} deg: \
                                 the calibration may be off",
                                m.x, m.y, m.z, c.seq, c.vertical_p50, cfg.threshold_deg
                            );
                        }
                    } else {
                        self.warned = false;
                    }
                }
            }
            None => self.frames_unfitted += 1,
        }
    }

    fn vertical_quantile(&self, q: f64) -> f64 {
        let n: u64 = self.vertical.iter().sum();
        if n == 0 {
            return f64::NAN;
        }
        let want = ((n as f64 * q).ceil() as u64).max(1);
        let mut acc = 0;
        for (i, c) in self.vertical.iter().enumerate() {
            acc += c;
            if acc >= want {
                return (i as f64 + 0.5) * BIN_PX;
            }
        }
        f64::NAN
    }

    /// The run's rotation error (rad) and its covariance from the scatter between frames: the information-
    /// weighted mean of the frames' estimates, each frame also weighted by Huber on its distance to the mean
    /// (in units of the robust spread of those distances).
    pub fn rotation(&self) -> Option<(Vector3<f64>, Matrix3<f64>)> {
        if self.fits.is_empty() {
            return None;
        }
        let mut fw = vec![1.0; self.fits.len()];
        let mut mean = Vector3::zeros();
        let mut a_sum = Matrix3::zeros();
        for it in 0..20 {
            let mut a = Matrix3::zeros();
            let mut b = Vector3::zeros();
            for ((om, info), w) in self.fits.iter().zip(&fw) {
                a += info * *w;
                b += info * om * *w;
            }
            let next = a.try_inverse()? * b;
            a_sum = a;
            let mut d: Vec<f64> = self.fits.iter().map(|(om, _)| (om - next).norm()).collect();
            let dist = d.clone();
            d.sort_by(f64::total_cmp);
            let k = 2.0 * 1.4826 * d[d.len() / 2].max(1e-12);
            for (w, x) in fw.iter_mut().zip(&dist) {
                *w = if *x <= k { 1.0 } else { k / x };
            }
            let step = (next - mean).norm();
            mean = next;
            if it > 0 && step < 1e-12 {
                break;
            }
        }
        let n = self.fits.len() as f64;
        let ainv = a_sum.try_inverse()?;
        let mut meat = Matrix3::zeros();
        for ((om, info), w) in self.fits.iter().zip(&fw) {
            let g = info * (om - mean) * *w;
            meat += g * g.transpose();
        }
        let cov = ainv * meat * ainv * if n > 1.0 { n / (n - 1.0) } else { f64::INFINITY };
        Some((mean, cov))
    }

    /// The stats JSON's `self_check` object.
    pub fn json(&self) -> Value {
        let mut m: Vec<u32> = self.matches.iter().copied().collect();
        m.sort_unstable();
        let matches_p50 = if m.is_empty() { Value::Null } else { json!(m[(m.len() - 1) / 2]) };
        let num = |x: f64| if x.is_finite() { json!((x * 1e4).round() / 1e4) } else { Value::Null };
        let (rot, sigma, axes) = match self.rotation() {
            Some((om, cov)) => {
                let s = Vector3::new(cov[(0, 0)].sqrt(), cov[(1, 1)].sqrt(), cov[(2, 2)].sqrt()).map(f64::to_degrees);
                (
                    json!([num(om.x.to_degrees()), num(om.y.to_degrees()), num(om.z.to_degrees())]),
                    num(s.max()),
                    json!([num(s.x), num(s.y), num(s.z)]),
                )
            }
            None => (Value::Null, Value::Null, Value::Null),
        };
        json!({
            "frames": self.frames,
            "frames_skipped": self.skipped,
            "frames_unfitted": self.frames_unfitted,
            "frames_failed": self.failed,
            "matches_p50": matches_p50,
            "vertical_px": { "p50": num(self.vertical_quantile(0.5)), "p95": num(self.vertical_quantile(0.95)) },
            "rotation_error_deg": rot,
            "rotation_sigma_deg": sigma,
            "rotation_sigma_axes_deg": axes,
            "warnings": self.warnings,
            "check_ms": { "p50": num(self.check_time.ms(0.5)), "p99": num(self.check_time.ms(0.99)) },
            "check_cpu_ms": { "p50": num(self.check_cpu.ms(0.5)), "p99": num(self.check_cpu.ms(0.99)) },
        })
    }
}

/// One line for the table `abvs run` prints, from the stats' `self_check` object.
pub fn summary_line(v: &Value) -> String {
    let f = |x: &Value| x.as_f64().map(|x| format!("{x:.3}")).unwrap_or_else(|| "-".into());
    let r = |k: usize| f(&v["rotation_error_deg"][k]);
    format!(
        "self-check: {} frames ({} skipped), matches p50 {}, |vertical| p50 {} p95 {} px, rotation error [{}, {}, {}] \
         deg (sigma {} deg), warnings {}",
        v["frames"],
        v["frames_skipped"],
        v["matches_p50"],
        f(&v["vertical_px"]["p50"]),
        f(&v["vertical_px"]["p95"]),
        r(0),
        r(1),
        r(2),
        f(&v["rotation_sigma_deg"]),
        v["warnings"]
    )
}

/// The CSV log's header.
pub const LOG_HEADER: &str = "seq,t_ns,l1_deg,l2_deg,l3_deg,r1_deg,r2_deg,r3_deg,matches,vertical_p50_px,\
                              vertical_p95_px,rot_x_deg,rot_y_deg,rot_z_deg,rot_sigma_x_deg,rot_sigma_y_deg,\
                              rot_sigma_z_deg";

fn log_row(c: &FrameCheck) -> String {
    let t = &c.theta;
    let f = |x: f64| if x.is_finite() { format!("{x:.6}") } else { String::new() };
    let (om, sg) = match &c.fit {
        Some(fit) => (fit.omega.map(f64::to_degrees), fit.sigma.map(f64::to_degrees)),
        None => (Vector3::repeat(f64::NAN), Vector3::repeat(f64::NAN)),
    };
    format!(
        "{},{},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{},{},{},{},{},{},{},{},{}",
        c.seq,
        c.t_frame_ns,
        t[0][0],
        t[0][1],
        t[0][2],
        t[1][0],
        t[1][1],
        t[1][2],
        c.matches,
        f(c.vertical_p50),
        f(c.vertical_p95),
        f(om.x),
        f(om.y),
        f(om.z),
        f(sg.x),
        f(sg.y),
        f(sg.z)
    )
}

/// The sink: copies every `every`-th rectified pair into a pooled job for the worker thread.
pub struct SelfCheckSink {
    cfg: SelfCheckConfig,
    tx: Option<Sender<Box<Job>>>,
    free: Receiver<Box<Job>>,
    worker: Option<JoinHandle<Summary>>,
    skipped: u64,
}

impl SelfCheckSink {
    /// Starts the worker for rectified pairs of `cam`'s size; creates the log file (if any) now.
    pub fn new(cfg: SelfCheckConfig, cam: &RectifiedCamera) -> Result<SelfCheckSink> {
        let mut log = match &cfg.log {
            Some(p) => {
                let f = std::fs::File::create(p).map_err(|e| RuntimeError::File {
                    path: p.clone(),
                    line: None,
                    msg: e.to_string(),
                })?;
                Some((std::io::BufWriter::new(f), p.clone()))
            }
            None => None,
        };
        if let Some((w, p)) = &mut log {
            writeln!(w, "{LOG_HEADER}").map_err(|e| RuntimeError::File {
                path: p.clone(),
                line: None,
                msg: e.to_string(),
            })?;
        }
        let mut matcher = Matcher::new(cfg.features, cfg.band_px)?;
        let n = (cam.width * cam.height) as usize;
        const POOL: usize = 2;
        let (free_tx, free_rx) = bounded::<Box<Job>>(POOL);
        let (tx, rx) = bounded::<Box<Job>>(POOL);
        for _ in 0..POOL {
            free_tx
                .send(Box::new(Job {
                    seq: 0,
                    t_frame_ns: 0,
                    theta: [[0.0; 3]; 2],
                    rot: Matrix3::identity(),
                    cam: *cam,
                    max_disp: 0.0,
                    left: vec![0; n],
                    right: vec![0; n],
                }))
                .expect("pool has room");
        }
        let wcfg = cfg.clone();
        let worker = std::thread::Builder::new()
            .name("self-check".into())
            .spawn(move || {
                if wcfg.background {
                    background_priority();
                }
                let mut sum = Summary::default();
                let mut matches = Vec::new();
                for job in rx.iter() {
                    let (t0, c0) = (std::time::Instant::now(), thread_cpu_ns());
                    let r = check_frame(&mut matcher, &job, &mut matches);
                    sum.check_time.record_ns(t0.elapsed().as_nanos() as i64);
                    sum.check_cpu.record_ns(thread_cpu_ns() - c0);
                    match r {
                        Ok(c) => {
                            sum.add(&c, &matches, &wcfg);
                            if let Some((w, p)) = &mut log {
                                if let Err(e) = writeln!(w, "{}", log_row(&c)) {
                                    eprintln!("warning: self-check log {}: {e}", p.display());
                                    log = None;
                                }
                            }
                        }
                        Err(e) => {
                            sum.failed += 1;
                            eprintln!("warning: self-check, frame {}: {e}", job.seq);
                        }
                    }
                    let _ = free_tx.send(job);
                }
                if let Some((mut w, p)) = log {
                    if let Err(e) = w.flush() {
                        eprintln!("warning: self-check log {}: {e}", p.display());
                    }
                }
                sum
            })
            .map_err(|e| RuntimeError::Invalid(format!("self-check: starting its thread: {e}")))?;
        Ok(SelfCheckSink { cfg, tx: Some(tx), free: free_rx, worker: Some(worker), skipped: 0 })
    }
}

/// CPU time of the calling thread (ns).
fn thread_cpu_ns() -> i64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: a valid clock id and a valid out pointer.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    ts.tv_sec * 1_000_000_000 + ts.tv_nsec
}

/// This thread runs only on idle CPU time: SCHED_IDLE, or nice 19 where that is refused (Linux applies
/// both per thread).
fn background_priority() {
    // SAFETY: plain system calls on the calling thread with a valid, initialised parameter.
    unsafe {
        let param = libc::sched_param { sched_priority: 0 };
        if libc::sched_setscheduler(0, libc::SCHED_IDLE, &param) != 0 {
            libc::setpriority(libc::PRIO_PROCESS, libc::gettid() as libc::id_t, 19);
        }
    }
}

impl Sink for SelfCheckSink {
    fn name(&self) -> &'static str {
        "self-check"
    }

    fn consume(&mut self, out: &Published) -> Result<()> {
        if out.seq % self.cfg.every.max(1) != 0 {
            return Ok(());
        }
        let Some(tx) = &self.tx else { return Ok(()) };
        let job = if self.cfg.blocking { self.free.recv().ok() } else { self.free.try_recv().ok() };
        let Some(mut job) = job else {
            self.skipped += 1;
            return Ok(());
        };
        if job.left.len() != out.left_rect.len() || job.cam != *out.cam {
            return Err(RuntimeError::Invalid("self-check: the rectified size changed".into()));
        }
        job.seq = out.seq;
        job.t_frame_ns = out.t_frame_ns;
        job.theta = *out.theta;
        job.rot = frame_rotation(out);
        job.max_disp = (out.cam.f * out.rect.baseline_m / self.cfg.min_depth_m) as f32 + 2.0;
        job.left.copy_from_slice(out.left_rect);
        job.right.copy_from_slice(out.right_rect);
        if tx.send(job).is_err() {
            self.skipped += 1;
        }
        Ok(())
    }

    fn finish(&mut self, stats: &mut RunStats) {
        self.tx = None;
        let Some(h) = self.worker.take() else { return };
        match h.join() {
            Ok(mut sum) => {
                sum.skipped = self.skipped;
                stats.extra.insert("self_check".into(), sum.json());
            }
            Err(_) => eprintln!("warning: the self-check thread panicked"),
        }
    }
}

impl Drop for SelfCheckSink {
    fn drop(&mut self) {
        self.tx = None;
        if let Some(h) = self.worker.take() {
            let _ = h.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use abvs_eye::Pose;

    fn so3(w: Vector3<f64>) -> Matrix3<f64> {
        nalgebra::Rotation3::new(w).into_inner()
    }

    /// Synthetic matches through the pipeline's own chain (moving extrinsic, rectification) with a home
    /// extrinsic that is wrong by `w`: the fit returns `w`.
    #[test]
    fn the_fit_recovers_a_home_rotation_error_in_the_left_home_frame() {
        let cam = RectifiedCamera::with_hfov(320, 240, 100.0);
        let home_true = Pose::new(so3(Vector3::new(0.001, -0.006, 0.002)), Vector3::new(-0.0655, 0.0002, 0.0002));
        let w = Vector3::new(0.2f64, -0.1, 0.15).map(f64::to_radians);
        let home_cal = Pose::new(home_true.r * so3(w), home_true.t);
        let rel_l = Pose::new(so3(Vector3::new(0.1, -0.2, 0.05)), Vector3::new(0.001, 0.0, 0.0005));
        let rel_r = Pose::new(so3(Vector3::new(0.08, -0.25, 0.0)), Vector3::new(0.0, 0.001, 0.0));
        let lr_true = crate::tasks::kinematics::moving_extrinsic(&rel_l, &rel_r, &home_true);
        let lr_cal = crate::tasks::kinematics::moving_extrinsic(&rel_l, &rel_r, &home_cal);
        let rect = crate::tasks::rectify::rectify(&lr_cal).unwrap();
        let mut rng = 12345u64;
        let mut rnd = || {
            rng = rng.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (rng >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut ms = Vec::new();
        for _ in 0..300 {
            // a point far away (translation effects vanish) seen by the left rectified camera
            let (u, v) = (10.0 + 300.0 * rnd(), 10.0 + 220.0 * rnd());
            let z = 50.0;
            let p_rect = Vector3::new((u - cam.cx) / cam.f * z, (v - cam.cy) / cam.f * z, z);
            let p_l = rect.rect_from_left.transpose() * p_rect;
            // the true right camera sees it; the pipeline rectifies that view with its (wrong) rotation
            let q = lr_true.r * p_l + lr_true.t;
            let d = rect.rect_from_right * q;
            let (ur, vr) = (cam.f * d.x / d.z + cam.cx, cam.f * d.y / d.z + cam.cy);
            ms.push(Match { xl: u as f32, yl: v as f32, xr: ur as f32, yr: vr as f32, ncc: 1.0 });
        }
        let m = rect.rect_from_left * rel_l.r.transpose();
        let fit = fit_rotation(&ms, &cam, &m).unwrap();
        let got = fit.omega.map(f64::to_degrees);
        // second-order terms of 0.2 deg and the f32 pixels: well under 0.01 deg
        assert!((got - w.map(f64::to_degrees)).abs().max() < 0.01, "{got:?}");
        // outliers do not move it
        for m in ms.iter_mut().step_by(10) {
            m.yr += 3.0;
        }
        let got = fit_rotation(&ms, &cam, &m).unwrap().omega.map(f64::to_degrees);
        assert!((got - w.map(f64::to_degrees)).abs().max() < 0.02, "{got:?}");
    }

    #[test]
    fn lucas_kanade_finds_a_sub_pixel_shift() {
        let (w, h) = (120usize, 80usize);
        let tex = |x: f64, y: f64| {
            (128.0
                + 50.0 * (0.37 * x + 0.11 * y).sin()
                + 40.0 * (0.23 * y - 0.17 * x).cos()
                + 20.0 * (0.52 * x + 0.41 * y).sin())
            .clamp(1.0, 255.0)
        };
        let left: Vec<u8> = (0..w * h).map(|i| tex((i % w) as f64, (i / w) as f64).round() as u8).collect();
        let (sx, sy) = (-7.3, 0.4);
        let right: Vec<u8> = (0..w * h).map(|i| tex((i % w) as f64 - sx, (i / w) as f64 - sy).round() as u8).collect();
        let m = refine(&left, &right, w, h, (60, 40), (53.0, 40.0)).expect("converges");
        assert!((m.xr - m.xl - sx as f32).abs() < 0.05 && (m.dy() - sy as f32).abs() < 0.05, "{m:?}");
    }
}
