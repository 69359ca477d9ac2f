//! Sub-pixel refinement of AprilGrid corners (saddle points, X-junctions) by an iterated,
//! re-centred quadratic fit (ROCHADE's model, Placht et al. 2014, iterated to its fixed point).
//!
//! Why not the detectors' own sub-pixel step: the `aprilgrid` crate fits the quadratic once, on
//! a patch centred on the *integer* pixel nearest the corner, after a sigma 1.5 blur and a cone
//! filter (support ~8 px). The blurred saddle is not a quadratic, so a fit centred up to half a
//! pixel off the corner is biased with the sub-pixel phase, and a support wider than the tag's
//! black border (2 of the tag's 10 bits, ~5.6 px for an 88 mm tag at 1.5 m) sees the data bits
//! and the neighbouring tags. Measured on rendered sessions (camcal/examples/accuracy_probe.rs):
//! corner error RMS 0.039 px as detected, 0.019 px after this refinement; OpenCV's cornerSubPix
//! (gradient orthogonality) on the same corners gave 0.057-0.071 px for window half-sizes 3-5.
//!
//! A locally point-symmetric pattern (two straight edges crossing, blurred by a symmetric PSF)
//! fitted with symmetric weights on a patch centred at its centre has zero linear terms, so the
//! centre is the fixed point of the iteration, whatever the fit's model error.
use crate::error::{CamcalError, Result};
use nalgebra::{Matrix2, SMatrix, SVector, Vector2};
use opencv::core::{Mat, Size, BORDER_REFLECT, CV_32F};
use opencv::imgproc;
use opencv::prelude::*;

/// Patch radius as a fraction of the tag side (the black border is 0.2 of it): small enough to
/// stay inside the border and the gap, large enough to average the noise.
pub const RADIUS_PER_TAG_SIDE: f64 = 0.18;
/// Smallest and largest patch radius, px.
pub const RADIUS_RANGE: (f64, f64) = (2.0, 8.0);
/// Pre-smoothing (Gaussian sigma, px): noise suppression; the fit's fixed point does not depend on it.
pub const SMOOTH_SIGMA: f64 = 1.2;
/// A refined corner further than this from the detector's estimate is not a saddle we trust.
pub const MAX_SHIFT_PX: f64 = 1.5;
/// Least saddle strength, sqrt(-det H) r^2: roughly the gray-level swing of the fitted surface over
/// the patch (an AprilGrid corner in a real or rendered image gives hundreds).
pub const MIN_SADDLE_GRAY: f64 = 5.0;
const MAX_ITERATIONS: usize = 20;
const CONVERGED_PX: f64 = 1e-4;
/// Sample spacing on the patch, px.
const STEP: f64 = 0.5;

/// The smoothed image the fits sample (bilinear), f32.
pub struct SaddleImage {
    data: Vec<f32>,
    width: usize,
    height: usize,
}

impl SaddleImage {
    /// Smooths an 8-bit grayscale image with [`SMOOTH_SIGMA`].
    pub fn new(gray: &Mat) -> Result<SaddleImage> {
        let mut f = Mat::default();
        gray.convert_to(&mut f, CV_32F, 1.0, 0.0)?;
        let mut s = Mat::default();
        imgproc::gaussian_blur(&f, &mut s, Size::new(0, 0), SMOOTH_SIGMA, SMOOTH_SIGMA, BORDER_REFLECT)?;
        let data = s.data_typed::<f32>()?.to_vec();
        Ok(SaddleImage { data, width: s.cols() as usize, height: s.rows() as usize })
    }

    fn bilinear(&self, x: f64, y: f64) -> f64 {
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (xi, yi) = (x0 as usize, y0 as usize);
        let row = |yy: usize| &self.data[yy * self.width + xi..yy * self.width + xi + 2];
        let (a, b) = (row(yi), row(yi + 1));
        (1.0 - fy) * ((1.0 - fx) * a[0] as f64 + fx * a[1] as f64) + fy * ((1.0 - fx) * b[0] as f64 + fx * b[1] as f64)
    }
}

/// The weighted least-squares quadratic fit on a fixed patch (offsets and weights do not depend on
/// where it is centred, so its pseudo-inverse is computed once per radius).
pub struct SaddleFit {
    radius: f64,
    offsets: Vec<(f64, f64)>,
    /// rows: the 6 coefficients (x^2, xy, y^2, x, y, 1) as linear functions of the samples
    pinv: Vec<[f64; 6]>,
}

impl SaddleFit {
    /// A fit with Gaussian weights exp(-d^2/r^2) on the samples within `radius` px.
    pub fn new(radius: f64) -> SaddleFit {
        let n = (radius / STEP).ceil() as i64;
        let mut offsets = Vec::new();
        let mut weights = Vec::new();
        for j in -n..=n {
            for i in -n..=n {
                let (x, y) = (i as f64 * STEP, j as f64 * STEP);
                let d2 = x * x + y * y;
                if d2 <= radius * radius {
                    offsets.push((x, y));
                    weights.push((-d2 / (radius * radius)).exp());
                }
            }
        }
        let basis = |(x, y): (f64, f64)| SVector::<f64, 6>::from([x * x, x * y, y * y, x, y, 1.0]);
        let mut ata = SMatrix::<f64, 6, 6>::zeros();
        for (o, w) in offsets.iter().zip(&weights) {
            let a = basis(*o);
            ata += *w * a * a.transpose();
        }
        // symmetric positive definite for any radius >= STEP (at least a 3x3 grid)
        let inv = ata.try_inverse().expect("quadratic fit on a 2-D grid of samples is well posed");
        let pinv = offsets
            .iter()
            .zip(&weights)
            .map(|(o, w)| {
                let c = inv * basis(*o) * *w;
                [c[0], c[1], c[2], c[3], c[4], c[5]]
            })
            .collect();
        SaddleFit { radius, offsets, pinv }
    }

    pub fn radius(&self) -> f64 {
        self.radius
    }

    /// Refines one saddle point from `p0`. None when the patch leaves the image, the surface is not a
    /// saddle there, or the fixed point is more than [`MAX_SHIFT_PX`] away from `p0`.
    pub fn refine(&self, img: &SaddleImage, p0: [f64; 2]) -> Option<[f64; 2]> {
        let margin = self.radius + MAX_SHIFT_PX + 2.0;
        let inside = |p: [f64; 2]| {
            p[0] >= margin && p[1] >= margin && p[0] < img.width as f64 - margin && p[1] < img.height as f64 - margin
        };
        let mut p = p0;
        for _ in 0..MAX_ITERATIONS {
            if !inside(p) {
                return None;
            }
            let mut c = [0.0; 6];
            for ((dx, dy), row) in self.offsets.iter().zip(&self.pinv) {
                let v = img.bilinear(p[0] + dx, p[1] + dy);
                for (ck, rk) in c.iter_mut().zip(row) {
                    *ck += rk * v;
                }
            }
            // stationary point of c0 x^2 + c1 xy + c2 y^2 + c3 x + c4 y + c5, a saddle when det < 0
            let h = Matrix2::new(2.0 * c[0], c[1], c[1], 2.0 * c[2]);
            let det = h.determinant();
            // a saddle, and one with some contrast over the patch (not noise on a flat area)
            if det >= 0.0 || (-det).sqrt() * self.radius * self.radius < MIN_SADDLE_GRAY {
                return None;
            }
            let mut d = h.lu().solve(&Vector2::new(-c[3], -c[4]))?;
            if d.norm() > 0.5 {
                d *= 0.5 / d.norm(); // far from the fixed point the quadratic is a poor guide: damp
            }
            p = [p[0] + d[0], p[1] + d[1]];
            if (p[0] - p0[0]).hypot(p[1] - p0[1]) > MAX_SHIFT_PX {
                return None;
            }
            if d.norm() < CONVERGED_PX {
                break;
            }
        }
        Some(p)
    }
}

/// Patch radius for a tag whose shortest side is `side_px` pixels.
pub fn radius_for_tag(side_px: f64) -> f64 {
    (RADIUS_PER_TAG_SIDE * side_px).clamp(RADIUS_RANGE.0, RADIUS_RANGE.1)
}

/// Refines the 4 corners of each tag (`tags`: id, corners) in place; a corner that does not
/// converge becomes None. Fits are shared between tags of the same radius (rounded to 0.25 px).
pub fn refine_tags(gray: &Mat, tags: &[(u32, [[f64; 2]; 4])]) -> Result<Vec<(u32, [Option<[f64; 2]>; 4])>> {
    if gray.typ() != opencv::core::CV_8UC1 {
        return Err(CamcalError::Invalid("saddle refinement needs an 8-bit grayscale image".into()));
    }
    let img = SaddleImage::new(gray)?;
    let mut fits: Vec<(i64, SaddleFit)> = Vec::new();
    let mut out = Vec::with_capacity(tags.len());
    for (id, c) in tags {
        let side = (0..4).map(|k| dist(c[k], c[(k + 1) % 4])).fold(f64::INFINITY, f64::min);
        let key = (radius_for_tag(side) * 4.0).round() as i64;
        let fit = match fits.iter().position(|(k, _)| *k == key) {
            Some(i) => &fits[i].1,
            None => {
                fits.push((key, SaddleFit::new(key as f64 / 4.0)));
                &fits.last().expect("just pushed").1
            }
        };
        out.push((*id, c.map(|p| fit.refine(&img, p))));
    }
    Ok(out)
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A synthetic X-junction at a known sub-pixel position, supersampled and blurred.
    fn x_junction(cx: f64, cy: f64, angle: f64) -> Mat {
        let (w, h) = (41usize, 41usize);
        let (s, c) = angle.sin_cos();
        let mut px = vec![0u8; w * h];
        for y in 0..h {
            for x in 0..w {
                let mut acc = 0.0f64;
                for sy in 0..8 {
                    for sx in 0..8 {
                        let (u, v) = (
                            x as f64 + (sx as f64 + 0.5) / 8.0 - 0.5 - cx,
                            y as f64 + (sy as f64 + 0.5) / 8.0 - 0.5 - cy,
                        );
                        // lines at `angle` and `angle + 70 deg` (perspective makes junctions non-orthogonal)
                        let a = u * c + v * s;
                        let (s2, c2) = (angle + 70f64.to_radians()).sin_cos();
                        let b = u * c2 + v * s2;
                        acc += if (a > 0.0) == (b > 0.0) { 30.0 } else { 220.0 };
                    }
                }
                px[y * w + x] = (acc / 64.0).round() as u8;
            }
        }
        let m = Mat::from_slice(&px).unwrap().reshape(1, h as i32).unwrap().try_clone().unwrap();
        let mut b = Mat::default();
        imgproc::gaussian_blur(&m, &mut b, Size::new(0, 0), 0.7, 0.7, BORDER_REFLECT).unwrap();
        b
    }

    #[test]
    fn finds_sub_pixel_junction_centres() {
        let mut worst: f64 = 0.0;
        for (k, (cx, cy)) in [(20.0, 20.0), (20.3, 19.6), (19.55, 20.45), (20.49, 20.01)].iter().enumerate() {
            let img = x_junction(*cx, *cy, 0.3 + 0.4 * k as f64);
            let si = SaddleImage::new(&img).unwrap();
            let fit = SaddleFit::new(4.0);
            let p = fit.refine(&si, [20.0, 20.0]).expect("converges");
            worst = worst.max(dist(p, [*cx, *cy]));
        }
        // the 8x8 supersampling and 8-bit quantisation alone leave a few thousandths of a pixel
        assert!(worst < 0.01, "worst error {worst} px");
    }

    #[test]
    fn refuses_what_is_not_a_saddle() {
        let flat = Mat::new_rows_cols_with_default(41, 41, opencv::core::CV_8UC1, 128.into()).unwrap();
        let si = SaddleImage::new(&flat).unwrap();
        assert!(SaddleFit::new(4.0).refine(&si, [20.0, 20.0]).is_none());
        let img = x_junction(20.0, 20.0, 0.2);
        let si = SaddleImage::new(&img).unwrap();
        assert!(SaddleFit::new(4.0).refine(&si, [2.0, 20.0]).is_none(), "patch leaves the image");
    }
}
