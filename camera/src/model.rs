//! Camera models: OpenCV's pinhole family (no distortion, plumb_bob, rational_polynomial) and OpenCV fisheye
//! (Kannala-Brandt on an equidistant base), with the exact formulas and coefficient orders OpenCV uses, so that
//! files written by OpenCV and by abvs mean the same thing.
//!
//! Pixel convention (OpenCV): pixel centres at integer coordinates, (0, 0) is the centre of the top-left pixel.
//! Camera frame (OpenCV, conventions.md): x right, y down, z along the optical axis.

use nalgebra::{Matrix2, Vector2, Vector3};

/// Lens distortion, OpenCV coefficient orders.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Distortion {
    /// Ideal pinhole.
    None,
    /// OpenCV "plumb_bob": k1 k2 p1 p2 k3.
    PlumbBob([f64; 5]),
    /// OpenCV rational polynomial (CALIB_RATIONAL_MODEL): k1 k2 p1 p2 k3 k4 k5 k6.
    Rational([f64; 8]),
    /// OpenCV fisheye (Kannala-Brandt): k1 k2 k3 k4 of theta_d = theta (1 + k1 theta^2 + ... + k4 theta^8).
    Fisheye([f64; 4]),
}

impl Distortion {
    /// The distortion_model string used in abvs (and ROS) YAML files.
    pub fn model_name(&self) -> &'static str {
        match self {
            Distortion::None | Distortion::PlumbBob(_) => "plumb_bob",
            Distortion::Rational(_) => "rational_polynomial",
            Distortion::Fisheye(_) => "fisheye",
        }
    }

    /// Coefficients in OpenCV order (an empty model writes five zeros, as OpenCV does).
    pub fn coefficients(&self) -> Vec<f64> {
        match self {
            Distortion::None => vec![0.0; 5],
            Distortion::PlumbBob(k) => k.to_vec(),
            Distortion::Rational(k) => k.to_vec(),
            Distortion::Fisheye(k) => k.to_vec(),
        }
    }

    /// Builds a model from its name and coefficients; `None` names an unknown model or a wrong count.
    pub fn from_name(name: &str, k: &[f64]) -> Option<Distortion> {
        match (name, k.len()) {
            ("fisheye" | "equidistant" | "kannala_brandt", 4) => Some(Distortion::Fisheye([k[0], k[1], k[2], k[3]])),
            ("plumb_bob" | "radtan" | "pinhole", 4) => Some(Distortion::PlumbBob([k[0], k[1], k[2], k[3], 0.0])),
            ("plumb_bob" | "radtan" | "pinhole", 5) => {
                if k.iter().all(|v| *v == 0.0) {
                    Some(Distortion::None)
                } else {
                    Some(Distortion::PlumbBob([k[0], k[1], k[2], k[3], k[4]]))
                }
            }
            ("plumb_bob" | "radtan" | "pinhole", 0) | ("none", 0) => Some(Distortion::None),
            ("rational_polynomial" | "rational", 8) => {
                Some(Distortion::Rational([k[0], k[1], k[2], k[3], k[4], k[5], k[6], k[7]]))
            }
            _ => None,
        }
    }
}

/// An intrinsically calibrated camera: image size, focal lengths and principal point in pixels, and distortion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub distortion: Distortion,
}

/// Largest field angle (rad) the fisheye model is used at: beyond the lens' ~120 deg the polynomial is not
/// monotonic any more for typical coefficients, and no real pixel sees it.
const FISHEYE_MAX_THETA: f64 = 1.5;

impl Camera {
    /// An ideal pinhole camera with the principal point at the image centre.
    pub fn pinhole(width: u32, height: u32, f: f64) -> Camera {
        Camera {
            width,
            height,
            fx: f,
            fy: f,
            cx: (width as f64 - 1.0) / 2.0,
            cy: (height as f64 - 1.0) / 2.0,
            distortion: Distortion::None,
        }
    }

    /// The nominal OV8856 eye camera: 1600x1200, a fisheye (Kannala-Brandt) lens with 118 deg horizontal field
    /// of view (the focal length is chosen so that the image's left and right edges sit at +-59 deg).
    pub fn ov8856() -> Camera {
        let k = [-0.01, 0.002, 0.0, 0.0];
        let half = 59f64.to_radians();
        let theta_d = fisheye_theta_d(&k, half);
        let (width, height) = (1600u32, 1200u32);
        let f = (width as f64 / 2.0) / theta_d;
        Camera {
            width,
            height,
            fx: f,
            fy: f,
            cx: (width as f64 - 1.0) / 2.0,
            cy: (height as f64 - 1.0) / 2.0,
            distortion: Distortion::Fisheye(k),
        }
    }

    /// The same lens at another resolution (binning / resizing): focal lengths and principal point scaled,
    /// respecting the pixel-centre convention.
    pub fn scaled(&self, width: u32, height: u32) -> Camera {
        let sx = width as f64 / self.width as f64;
        let sy = height as f64 / self.height as f64;
        Camera {
            width,
            height,
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: (self.cx + 0.5) * sx - 0.5,
            cy: (self.cy + 0.5) * sy - 0.5,
            distortion: self.distortion,
        }
    }

    /// Horizontal field of view (deg) spanned by the image's outer pixel edges through the principal row.
    pub fn hfov_deg(&self) -> f64 {
        let left = self.unproject(&Vector2::new(-0.5, self.cy));
        let right = self.unproject(&Vector2::new(self.width as f64 - 0.5, self.cy));
        match (left, right) {
            (Some(l), Some(r)) => l.angle(&r).to_degrees(),
            _ => f64::NAN,
        }
    }

    pub fn is_fisheye(&self) -> bool {
        matches!(self.distortion, Distortion::Fisheye(_))
    }

    /// Camera-frame point -> pixel. `None` for points behind a pinhole-family camera or beyond the fisheye
    /// model's valid field angle.
    pub fn project(&self, p: &Vector3<f64>) -> Option<Vector2<f64>> {
        let d = match self.distortion {
            Distortion::Fisheye(k) => {
                let r = (p.x * p.x + p.y * p.y).sqrt();
                let theta = r.atan2(p.z);
                if !theta.is_finite() || theta > FISHEYE_MAX_THETA {
                    return None;
                }
                if r < 1e-300 {
                    Vector2::zeros()
                } else {
                    let s = fisheye_theta_d(&k, theta) / r;
                    Vector2::new(p.x * s, p.y * s)
                }
            }
            _ => {
                if p.z <= 1e-12 {
                    return None;
                }
                self.distort_normalized(&Vector2::new(p.x / p.z, p.y / p.z))
            }
        };
        Some(Vector2::new(self.fx * d.x + self.cx, self.fy * d.y + self.cy))
    }

    /// Pixel -> unit-norm ray direction in the camera frame. `None` where the model cannot be inverted
    /// (beyond the valid field angle, or the iteration does not converge).
    pub fn unproject(&self, px: &Vector2<f64>) -> Option<Vector3<f64>> {
        let d = Vector2::new((px.x - self.cx) / self.fx, (px.y - self.cy) / self.fy);
        match self.distortion {
            Distortion::None => Some(Vector3::new(d.x, d.y, 1.0).normalize()),
            Distortion::Fisheye(k) => {
                let theta_d = d.norm();
                if theta_d < 1e-300 {
                    return Some(Vector3::z());
                }
                let theta = fisheye_theta(&k, theta_d)?;
                let (s, c) = theta.sin_cos();
                Some(Vector3::new(s * d.x / theta_d, s * d.y / theta_d, c))
            }
            _ => {
                let u = self.undistort_normalized(&d)?;
                Some(Vector3::new(u.x, u.y, 1.0).normalize())
            }
        }
    }

    /// Pinhole-family distortion of a normalized image point (x/z, y/z), OpenCV's formula.
    fn distort_normalized(&self, x: &Vector2<f64>) -> Vector2<f64> {
        let (k, p) = match self.distortion {
            Distortion::None | Distortion::Fisheye(_) => return *x,
            Distortion::PlumbBob(c) => ([c[0], c[1], c[4], 0.0, 0.0, 0.0], [c[2], c[3]]),
            Distortion::Rational(c) => ([c[0], c[1], c[4], c[5], c[6], c[7]], [c[2], c[3]]),
        };
        let r2 = x.x * x.x + x.y * x.y;
        let radial = (1.0 + r2 * (k[0] + r2 * (k[1] + r2 * k[2]))) / (1.0 + r2 * (k[3] + r2 * (k[4] + r2 * k[5])));
        let xy = x.x * x.y;
        Vector2::new(
            x.x * radial + 2.0 * p[0] * xy + p[1] * (r2 + 2.0 * x.x * x.x),
            x.y * radial + p[0] * (r2 + 2.0 * x.y * x.y) + 2.0 * p[1] * xy,
        )
    }

    /// Inverts `distort_normalized` by Newton's method (OpenCV's fixed-point undistortion is not accurate
    /// enough for wide lenses).
    fn undistort_normalized(&self, d: &Vector2<f64>) -> Option<Vector2<f64>> {
        let mut x = *d;
        for _ in 0..50 {
            let f = self.distort_normalized(&x) - d;
            if f.norm() < 1e-13 {
                return Some(x);
            }
            let h = 1e-7;
            let jx = (self.distort_normalized(&(x + Vector2::new(h, 0.0))) - self.distort_normalized(&x)) / h;
            let jy = (self.distort_normalized(&(x + Vector2::new(0.0, h))) - self.distort_normalized(&x)) / h;
            let j = Matrix2::from_columns(&[jx, jy]);
            let step = j.try_inverse()? * f;
            x -= step;
            if !x.x.is_finite() || !x.y.is_finite() {
                return None;
            }
        }
        (self.distort_normalized(&x) - d).norm().lt(&1e-9).then_some(x)
    }

    /// 3x3 camera matrix, row major.
    pub fn k_matrix(&self) -> [[f64; 3]; 3] {
        [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]]
    }
}

/// theta_d(theta) of the OpenCV fisheye model.
fn fisheye_theta_d(k: &[f64; 4], theta: f64) -> f64 {
    let t2 = theta * theta;
    theta * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))
}

/// Inverse of `fisheye_theta_d` by Newton's method, restricted to the monotonic range.
fn fisheye_theta(k: &[f64; 4], theta_d: f64) -> Option<f64> {
    let mut t = theta_d;
    for _ in 0..30 {
        let t2 = t * t;
        let f = fisheye_theta_d(k, t) - theta_d;
        let df = 1.0 + t2 * (3.0 * k[0] + t2 * (5.0 * k[1] + t2 * (7.0 * k[2] + t2 * 9.0 * k[3])));
        if df <= 0.0 {
            return None;
        }
        let step = f / df;
        t -= step;
        if step.abs() < 1e-15 {
            break;
        }
    }
    let ok = t.is_finite() && (0.0..=FISHEYE_MAX_THETA).contains(&t) && (fisheye_theta_d(k, t) - theta_d).abs() < 1e-10;
    ok.then_some(t)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cameras() -> Vec<Camera> {
        let mut plumb = Camera::pinhole(640, 480, 500.0);
        plumb.distortion = Distortion::PlumbBob([-0.28, 0.07, 0.001, -0.0005, 0.0]);
        let mut rational = Camera::pinhole(1600, 1200, 900.0);
        rational.distortion = Distortion::Rational([0.05, 0.0, 0.0003, 0.0002, 0.0, 0.15, 0.0, 0.0]);
        vec![Camera::ov8856(), Camera::ov8856().scaled(320, 240), Camera::pinhole(320, 240, 240.0), plumb, rational]
    }

    #[test]
    fn ov8856_has_118_deg_hfov() {
        let c = Camera::ov8856();
        assert!((c.hfov_deg() - 118.0).abs() < 0.2, "hfov {}", c.hfov_deg());
        let s = c.scaled(320, 240);
        assert!((s.hfov_deg() - 118.0).abs() < 0.2);
    }

    #[test]
    fn project_unproject_round_trip_over_the_image() {
        for cam in cameras() {
            let mut worst: f64 = 0.0;
            for j in 0..=12 {
                for i in 0..=16 {
                    let px = Vector2::new(
                        i as f64 / 16.0 * (cam.width - 1) as f64,
                        j as f64 / 12.0 * (cam.height - 1) as f64,
                    );
                    let ray = cam.unproject(&px).unwrap_or_else(|| panic!("{cam:?} cannot unproject {px}"));
                    assert!((ray.norm() - 1.0).abs() < 1e-12);
                    let back = cam.project(&(ray * 2.5)).unwrap();
                    worst = worst.max((back - px).norm());
                }
            }
            assert!(worst < 1e-7, "{:?}: worst round trip {worst} px", cam.distortion);
        }
    }

    #[test]
    fn fisheye_matches_opencv_formula_at_a_known_point() {
        // theta = atan(r); theta_d = theta (1 + k1 theta^2 + ...); x' = theta_d / r * a  (OpenCV fisheye docs)
        let cam = Camera::ov8856();
        let p = Vector3::new(0.3, -0.2, 1.0);
        let r = (0.09f64 + 0.04).sqrt();
        let th = r.atan();
        let Distortion::Fisheye(k) = cam.distortion else { unreachable!() };
        let thd = th * (1.0 + k[0] * th.powi(2) + k[1] * th.powi(4) + k[2] * th.powi(6) + k[3] * th.powi(8));
        let expect = Vector2::new(cam.fx * thd / r * 0.3 + cam.cx, cam.fy * thd / r * -0.2 + cam.cy);
        assert!((cam.project(&p).unwrap() - expect).norm() < 1e-9);
    }

    #[test]
    fn behind_the_camera_is_refused() {
        assert!(Camera::pinhole(320, 240, 240.0).project(&Vector3::new(0.0, 0.0, -1.0)).is_none());
        assert!(Camera::ov8856().project(&Vector3::new(0.0, 0.0, -1.0)).is_none());
    }

    #[test]
    fn scaling_keeps_pixel_edges() {
        let c = Camera::pinhole(1600, 1200, 800.0);
        let s = c.scaled(800, 600);
        // the image's left edge (-0.5) maps to the same ray at both resolutions
        let a = c.unproject(&Vector2::new(-0.5, c.cy)).unwrap();
        let b = s.unproject(&Vector2::new(-0.5, s.cy)).unwrap();
        assert!((a - b).norm() < 1e-12);
    }

    #[test]
    fn distortion_names_round_trip() {
        for d in [
            Distortion::None,
            Distortion::PlumbBob([0.1, 0.2, 0.3, 0.4, 0.5]),
            Distortion::Fisheye([0.1, 0.2, 0.3, 0.4]),
        ] {
            assert_eq!(Distortion::from_name(d.model_name(), &d.coefficients()), Some(d));
        }
        assert_eq!(Distortion::from_name("fisheye", &[0.1]), None);
        assert_eq!(Distortion::from_name("brown", &[0.0; 5]), None);
    }
}
