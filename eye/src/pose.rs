//! Orientation and pose conventions (conventions.md): Fick angles `R = Ry(gamma) Rx(alpha) Rz(beta)`
//! and the camera pose relative to home `P = [alpha, beta, gamma (deg), x, y, z (mm)]`.
use nalgebra::{Matrix3, Rotation3, Vector3};

/// Fick angles in radians: alpha = pitch (about x), beta = roll (about z), gamma = yaw (about y).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Fick {
    pub alpha: f64,
    pub beta: f64,
    pub gamma: f64,
}

impl Fick {
    pub fn from_deg(d: [f64; 3]) -> Self {
        Fick { alpha: d[0].to_radians(), beta: d[1].to_radians(), gamma: d[2].to_radians() }
    }
    pub fn to_deg(self) -> [f64; 3] {
        [self.alpha.to_degrees(), self.beta.to_degrees(), self.gamma.to_degrees()]
    }
    /// `R = Ry(gamma) . Rx(alpha) . Rz(beta)`.
    pub fn to_matrix(self) -> Matrix3<f64> {
        let (sa, ca) = self.alpha.sin_cos();
        let (sb, cb) = self.beta.sin_cos();
        let (sg, cg) = self.gamma.sin_cos();
        // Rx(a) Rz(b) first, then Ry(g) on the left (expanded by hand: hot path of IK).
        let m = Matrix3::new(cb, -sb, 0.0, ca * sb, ca * cb, -sa, sa * sb, sa * cb, ca);
        let ry = Matrix3::new(cg, 0.0, sg, 0.0, 1.0, 0.0, -sg, 0.0, cg);
        ry * m
    }
    /// Inverse of [`Fick::to_matrix`]; alpha in [-90, 90] deg (gimbal lock at |alpha| = 90).
    pub fn from_matrix(r: &Matrix3<f64>) -> Self {
        let alpha = (-r[(1, 2)]).clamp(-1.0, 1.0).asin();
        let beta = r[(1, 0)].atan2(r[(1, 1)]);
        let gamma = r[(0, 2)].atan2(r[(2, 2)]);
        Fick { alpha, beta, gamma }
    }
}

/// A rigid transform (rotation + translation in mm). `apply(p) = R p + t`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    pub r: Matrix3<f64>,
    pub t: Vector3<f64>,
}

impl Default for Pose {
    fn default() -> Self {
        Pose::identity()
    }
}

impl Pose {
    pub fn identity() -> Self {
        Pose { r: Matrix3::identity(), t: Vector3::zeros() }
    }
    pub fn new(r: Matrix3<f64>, t: Vector3<f64>) -> Self {
        Pose { r, t }
    }
    pub fn inverse(&self) -> Pose {
        let rt = self.r.transpose();
        Pose { r: rt, t: -(rt * self.t) }
    }
    /// `self * other` (apply `other` first).
    pub fn compose(&self, other: &Pose) -> Pose {
        Pose { r: self.r * other.r, t: self.r * other.t + self.t }
    }
    /// From the file layout `[alpha, beta, gamma (deg), x, y, z (mm)]`.
    pub fn from_p6(p: &[f64; 6]) -> Pose {
        Pose { r: Fick::from_deg([p[0], p[1], p[2]]).to_matrix(), t: Vector3::new(p[3], p[4], p[5]) }
    }
    /// To the file layout `[alpha, beta, gamma (deg), x, y, z (mm)]`.
    pub fn to_p6(&self) -> [f64; 6] {
        let f = Fick::from_matrix(&self.r).to_deg();
        [f[0], f[1], f[2], self.t.x, self.t.y, self.t.z]
    }
}

/// Rotation vector (axis * angle, rad) of a rotation matrix. Uses atan2 of the skew and
/// symmetric parts, accurate to machine precision for small angles (where acos of the trace,
/// as in nalgebra's `scaled_axis`, loses half the digits); nalgebra handles angles near pi.
pub fn rotation_vector(r: &Matrix3<f64>) -> Vector3<f64> {
    let v = Vector3::new(r[(2, 1)] - r[(1, 2)], r[(0, 2)] - r[(2, 0)], r[(1, 0)] - r[(0, 1)]) * 0.5;
    let s = v.norm();
    let c = 0.5 * (r.trace() - 1.0);
    let th = s.atan2(c);
    if th > std::f64::consts::PI - 1e-3 {
        return Rotation3::from_matrix_unchecked(*r).scaled_axis();
    }
    let k = if s < 1e-12 { 1.0 + th * th / 6.0 } else { th / s };
    v * k
}

/// Rotation matrix from a rotation vector (rad), Rodrigues.
pub fn exp_so3(w: &Vector3<f64>) -> Matrix3<f64> {
    let th2 = w.norm_squared();
    let k = skew(w);
    if th2 < 1e-24 {
        return Matrix3::identity() + k;
    }
    let th = th2.sqrt();
    let (s, c) = th.sin_cos();
    Matrix3::identity() + k * (s / th) + k * k * ((1.0 - c) / th2)
}

pub fn skew(w: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -w.z, w.y, w.z, 0.0, -w.x, -w.y, w.x, 0.0)
}

/// Angle (deg) of the rotation taking `a` to `b`.
pub fn rotation_angle_deg(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    let m = a.transpose() * b;
    (((m.trace() - 1.0) / 2.0).clamp(-1.0, 1.0)).acos().to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fick_round_trip() {
        for a in [-30.0, -7.0, 0.0, 12.5, 30.0] {
            for b in [-15.0, 0.0, 3.0, 15.0] {
                for g in [-30.0, 0.0, 29.0] {
                    let f = Fick::from_deg([a, b, g]);
                    let back = Fick::from_matrix(&f.to_matrix()).to_deg();
                    for (x, y) in back.iter().zip([a, b, g]) {
                        assert!((x - y).abs() < 1e-12, "{back:?} vs {:?}", [a, b, g]);
                    }
                }
            }
        }
    }

    #[test]
    fn fick_order_is_ry_rx_rz() {
        let f = Fick::from_deg([10.0, 20.0, 30.0]);
        let rx = Rotation3::from_axis_angle(&Vector3::x_axis(), f.alpha);
        let ry = Rotation3::from_axis_angle(&Vector3::y_axis(), f.gamma);
        let rz = Rotation3::from_axis_angle(&Vector3::z_axis(), f.beta);
        let want = (ry * rx * rz).into_inner();
        assert!((f.to_matrix() - want).norm() < 1e-14);
    }

    #[test]
    fn exp_log_round_trip() {
        for w in [Vector3::new(0.3, -0.2, 0.9), Vector3::new(1e-7, 2e-7, -3e-8), Vector3::new(0.0, 3.1, 0.0)] {
            let back = rotation_vector(&exp_so3(&w));
            assert!((back - w).norm() < 1e-13 * (1.0 + w.norm()) || (back - w).norm() / w.norm() < 1e-9, "{w} {back}");
        }
        let tiny = Vector3::new(1e-7, 2e-7, -3e-8);
        assert!((rotation_vector(&exp_so3(&tiny)) - tiny).norm() < 1e-20);
    }
}
