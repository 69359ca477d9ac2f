//! Kinematics of a coaxial 3-DoF spherical parallel mechanism (conventions.md), for any leg
//! geometry: the nominal one and the perturbed ones of real units share this one solver.
//!
//! Leg i: the proximal link turns by `theta_i` about its input axis `a_i` (right-handed; +z
//! nominally), carrying the distal-joint axis `w_i(theta) = Rot(a_i, theta_i) w_i0`. The
//! platform-joint axis is `R v_i0`. Loop closure: `f_i = w_i . (R v_i0) - cos d2_i = 0`.
//!
//! Orientation updates are left-multiplicative rotation vectors (`R <- exp(d) R`, base
//! frame), so the constraint Jacobian is `df_i/dd = (R v_i0 x w_i)^T` and the input Jacobian
//! is `df_i/dtheta_i = (a_i x w_i) . (R v_i0)`, both analytic.
use crate::error::{EyeError, Result};
use crate::pose::{exp_so3, Fick};
use nalgebra::{Matrix3, Vector3};
use std::f64::consts::PI;

/// One leg of the SPM, all vectors unit length in the base frame B.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Leg {
    /// Input (proximal) rotation axis; theta is right-handed about it.
    pub axis: Vector3<f64>,
    /// Distal-joint axis at theta = 0.
    pub w0: Vector3<f64>,
    /// Platform-joint axis at the identity orientation.
    pub v0: Vector3<f64>,
    /// cos of the distal link angle d2.
    pub cos_d2: f64,
}

/// Leg-by-leg description of a spherical parallel mechanism; see the module doc.
#[derive(Debug, Clone, PartialEq)]
pub struct SpmGeometry {
    pub legs: [Leg; 3],
    /// IK root (+1 or -1) of the working mode per leg, found by continuity with home.
    branch: [f64; 3],
    /// Sign of det(constraint Jacobian) in the working mode (it changes only through a
    /// parallel singularity, so a solution with the other sign is another assembly mode).
    det_sign: f64,
    /// Refuse configurations whose singularity measure falls below this.
    pub singular_limit: f64,
}

/// Nominal design values (conventions.md).
pub const NOMINAL_D1_DEG: f64 = 60.0;
pub const NOMINAL_D2_DEG: f64 = 90.0;
pub const NOMINAL_PSI_DEG: [f64; 3] = [90.0, 210.0, 330.0];
/// Default refusal threshold of [`Singularity::measure`]. Over the paper's workspace the
/// nominal geometry stays above 0.2 (parallel, worst at the corners) and 0.86 (serial); see the
/// `singularity_margin_over_workspace` test. 0.05 leaves room for units whose workspace is
/// shifted by a few degrees while refusing poses that genuinely approach a singularity.
pub const DEFAULT_SINGULAR_LIMIT: f64 = 0.05;

/// Per-leg construction parameters (degrees); perturbations of real units enter here.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LegParams {
    pub psi_deg: f64,
    pub d1_deg: f64,
    pub d2_deg: f64,
    /// Tilt of the input axis: rotations about x then y of B applied to the whole proximal link.
    pub axis_tilt_deg: [f64; 2],
    /// Platform-joint axis error: azimuth (in the platform plane) and elevation (out of it).
    pub platform_axis_deg: [f64; 2],
}

impl LegParams {
    pub fn nominal(i: usize) -> Self {
        LegParams {
            psi_deg: NOMINAL_PSI_DEG[i],
            d1_deg: NOMINAL_D1_DEG,
            d2_deg: NOMINAL_D2_DEG,
            axis_tilt_deg: [0.0; 2],
            platform_axis_deg: [0.0; 2],
        }
    }

    pub fn to_leg(&self) -> Leg {
        let psi = self.psi_deg.to_radians();
        let d1 = self.d1_deg.to_radians();
        let tilt = tilt_matrix(self.axis_tilt_deg);
        let axis = tilt * Vector3::z();
        let w0 = tilt * Vector3::new(d1.sin() * psi.cos(), d1.sin() * psi.sin(), -d1.cos());
        let az = psi + PI / 2.0 + self.platform_axis_deg[0].to_radians();
        let el = self.platform_axis_deg[1].to_radians();
        let v0 = Vector3::new(az.cos() * el.cos(), az.sin() * el.cos(), el.sin());
        Leg { axis, w0, v0, cos_d2: self.d2_deg.to_radians().cos() }
    }
}

fn tilt_matrix(t: [f64; 2]) -> Matrix3<f64> {
    let (sx, cx) = t[0].to_radians().sin_cos();
    let (sy, cy) = t[1].to_radians().sin_cos();
    let rx = Matrix3::new(1.0, 0.0, 0.0, 0.0, cx, -sx, 0.0, sx, cx);
    let ry = Matrix3::new(cy, 0.0, sy, 0.0, 1.0, 0.0, -sy, 0.0, cy);
    ry * rx
}

/// The smallest and largest eigenvalues of a symmetric 3x3 matrix in closed form (the trigonometric solution
/// of its characteristic cubic; O. K. Smith, CACM 1961); None where they are not finite.
fn sym3_eigen_extremes(a: &Matrix3<f64>) -> Option<(f64, f64)> {
    let q = a.trace() / 3.0;
    let off = a[(0, 1)].powi(2) + a[(0, 2)].powi(2) + a[(1, 2)].powi(2);
    let p2 = (0..3).map(|i| (a[(i, i)] - q).powi(2)).sum::<f64>() + 2.0 * off;
    if !p2.is_finite() {
        return None;
    }
    if p2 == 0.0 {
        return Some((q, q)); // a multiple of the identity
    }
    let p = (p2 / 6.0).sqrt();
    let b = (a - Matrix3::identity() * q) / p;
    let phi = (b.determinant() / 2.0).clamp(-1.0, 1.0).acos() / 3.0;
    Some((q + 2.0 * p * (phi + 2.0 * PI / 3.0).cos(), q + 2.0 * p * phi.cos()))
}

/// Singularity report of one configuration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Singularity {
    /// Inverse condition number (sigma_min / sigma_max) of the constraint Jacobian: 0 at a
    /// parallel (type II) singularity, where the platform gains a free motion.
    pub parallel: f64,
    /// Smallest `sin` of the half-gap between the two IK roots over the legs: 0 at a serial
    /// (type I) singularity, where a leg is fully stretched or folded.
    pub serial: f64,
}

impl Singularity {
    /// The single number compared with the refusal limit.
    pub fn measure(&self) -> f64 {
        self.parallel.min(self.serial)
    }
}

/// A converged FK solution.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FkSolution {
    pub r: Matrix3<f64>,
    pub iterations: u32,
    /// max |f_i| at the solution.
    pub residual: f64,
}

const FK_TOL: f64 = 1e-13;
const FK_MAX_ITER: u32 = 30;

impl Default for SpmGeometry {
    fn default() -> Self {
        Self::nominal()
    }
}

impl SpmGeometry {
    /// The design geometry of conventions.md: d1 = 60, d2 = 90, psi = 90/210/330 deg.
    pub fn nominal() -> Self {
        Self::from_params(&[LegParams::nominal(0), LegParams::nominal(1), LegParams::nominal(2)])
    }

    pub fn from_params(p: &[LegParams; 3]) -> Self {
        Self::from_legs([p[0].to_leg(), p[1].to_leg(), p[2].to_leg()])
    }

    /// Builds the solver for given legs; the working mode is the one continuous with the
    /// identity orientation at theta = 0 (home).
    pub fn from_legs(legs: [Leg; 3]) -> Self {
        let mut g = SpmGeometry { legs, branch: [-1.0; 3], det_sign: 1.0, singular_limit: DEFAULT_SINGULAR_LIMIT };
        let eye = Matrix3::identity();
        for i in 0..3 {
            // The root nearer theta = 0 at the identity orientation is the working mode.
            if let Some((delta, gap)) = g.leg_roots(i, &eye) {
                let minus = wrap(delta - gap).abs();
                let plus = wrap(delta + gap).abs();
                g.branch[i] = if plus < minus { 1.0 } else { -1.0 };
            }
        }
        let j = g.constraint_jacobian(&eye, &[0.0; 3]);
        g.det_sign = if j.determinant() >= 0.0 { 1.0 } else { -1.0 };
        g
    }

    /// Distal-joint axis of leg i at link angle theta (rad).
    #[inline]
    pub fn w(&self, i: usize, theta: f64) -> Vector3<f64> {
        let l = &self.legs[i];
        let (s, c) = theta.sin_cos();
        let a = l.axis;
        l.w0 * c + a.cross(&l.w0) * s + a * (a.dot(&l.w0) * (1.0 - c))
    }

    /// Loop-closure residuals f_i(R, theta).
    #[inline]
    pub fn constraints(&self, r: &Matrix3<f64>, theta: &[f64; 3]) -> Vector3<f64> {
        Vector3::from_fn(|i, _| self.w(i, theta[i]).dot(&(r * self.legs[i].v0)) - self.legs[i].cos_d2)
    }

    /// df/d(rotation vector applied on the left), rows `(R v_i0 x w_i)^T`.
    pub fn constraint_jacobian(&self, r: &Matrix3<f64>, theta: &[f64; 3]) -> Matrix3<f64> {
        let mut j = Matrix3::zeros();
        for i in 0..3 {
            let row = (r * self.legs[i].v0).cross(&self.w(i, theta[i]));
            j.set_row(i, &row.transpose());
        }
        j
    }

    /// Diagonal of df/dtheta: `(a_i x w_i) . (R v_i0)`.
    pub fn input_jacobian(&self, r: &Matrix3<f64>, theta: &[f64; 3]) -> Vector3<f64> {
        Vector3::from_fn(|i, _| {
            let l = &self.legs[i];
            l.axis.cross(&self.w(i, theta[i])).dot(&(r * l.v0))
        })
    }

    /// Angular-velocity Jacobian of the FK: `omega = J_fk thetadot` (base frame, rad per rad),
    /// from differentiating f(R(theta), theta) = 0: `J_c omega + diag(J_in) thetadot = 0`.
    pub fn fk_jacobian(&self, r: &Matrix3<f64>, theta: &[f64; 3]) -> Result<Matrix3<f64>> {
        let jc = self.constraint_jacobian(r, theta);
        let d = Matrix3::from_diagonal(&self.input_jacobian(r, theta));
        let inv = jc.try_inverse().ok_or_else(|| EyeError::NearSingular {
            what: format!("constraint Jacobian singular at theta {:?} rad", theta),
            measure: 0.0,
            limit: self.singular_limit,
        })?;
        Ok(-(inv * d))
    }

    /// (delta, gap) of the IK equation of leg i: roots `theta = delta +- gap`; None if the
    /// leg cannot reach the platform axis.
    #[inline]
    fn leg_roots(&self, i: usize, r: &Matrix3<f64>) -> Option<(f64, f64)> {
        let l = &self.legs[i];
        let v = r * l.v0;
        let aw = l.axis.dot(&l.w0);
        let av = l.axis.dot(&v);
        // w(theta).v = P cos + Q sin + aw av
        let p = l.w0.dot(&v) - aw * av;
        let q = l.axis.cross(&l.w0).dot(&v);
        let c = l.cos_d2 - aw * av;
        let rho = p.hypot(q);
        if rho < 1e-15 || c.abs() > rho {
            return None;
        }
        Some((q.atan2(p), (c / rho).acos()))
    }

    /// Closed-form inverse kinematics: link angles (rad, in (-pi, pi]) on the working-mode branch.
    pub fn ik(&self, r: &Matrix3<f64>) -> Result<[f64; 3]> {
        let mut th = [0.0; 3];
        for (i, t) in th.iter_mut().enumerate() {
            let (delta, gap) = self.leg_roots(i, r).ok_or_else(|| {
                EyeError::Unreachable(format!(
                    "leg {} cannot reach orientation (Fick {:?} deg)",
                    i + 1,
                    Fick::from_matrix(r).to_deg()
                ))
            })?;
            *t = wrap(delta + self.branch[i] * gap);
        }
        Ok(th)
    }

    /// IK with a singularity check.
    pub fn ik_checked(&self, r: &Matrix3<f64>) -> Result<[f64; 3]> {
        let th = self.ik(r)?;
        self.check_regular(r, &th)?;
        Ok(th)
    }

    pub fn singularity(&self, r: &Matrix3<f64>, theta: &[f64; 3]) -> Singularity {
        let j = self.constraint_jacobian(r, theta);
        let sv = j.singular_values();
        let (mx, mn) = (sv.max(), sv.min());
        let parallel = if mx > 0.0 { mn / mx } else { 0.0 };
        let mut serial: f64 = 1.0;
        for i in 0..3 {
            serial = serial.min(self.leg_roots(i, r).map(|(_, gap)| gap.sin()).unwrap_or(0.0));
        }
        Singularity { parallel, serial }
    }

    pub fn check_singularity(&self, r: &Matrix3<f64>, theta: &[f64; 3]) -> Result<Singularity> {
        let s = self.singularity(r, theta);
        if s.measure() < self.singular_limit {
            return Err(EyeError::NearSingular {
                what: format!(
                    "theta = {:?} deg (parallel {:.4}, serial {:.4})",
                    theta.map(f64::to_degrees),
                    s.parallel,
                    s.serial
                ),
                measure: s.measure(),
                limit: self.singular_limit,
            });
        }
        Ok(s)
    }

    /// [`SpmGeometry::check_singularity`]'s verdict without its report, the constraint Jacobian's conditioning
    /// taken from the eigenvalues of `J^T J` in closed form where it is clearly above the limit. Why: every FK
    /// solve and checked IK of the unit model checks, and nalgebra's 3x3 SVD (an eigen-decomposition with its
    /// vectors, then a QR for U) was a fifth of the discrepancy workflow's time (perf on calib/tests/explain.rs
    /// `finds_hidden_encoder_scale`). The closed form's error in `lambda_min / lambda_max` is below 1e-7 (the
    /// arccos near a double root), so within 1e-6 of the limit the exact check decides: the verdict is
    /// always `check_singularity`'s.
    pub fn check_regular(&self, r: &Matrix3<f64>, theta: &[f64; 3]) -> Result<()> {
        let j = self.constraint_jacobian(r, theta);
        let lim = self.singular_limit;
        let clearly = match sym3_eigen_extremes(&j.tr_mul(&j)) {
            Some((lo, hi)) if hi > 0.0 => lo / hi >= lim * lim + 1e-6,
            _ => false,
        };
        // the serial measure as check_singularity computes it (min over the legs, from 1.0), only when needed
        if clearly && (0..3).all(|i| self.leg_roots(i, r).map(|(_, gap)| gap.sin()).unwrap_or(0.0).min(1.0) >= lim) {
            return Ok(());
        }
        self.check_singularity(r, theta).map(|_| ())
    }

    /// Newton FK warm-started from `r0` (e.g. the previous frame's orientation). Converges
    /// quadratically to |f| < 1e-13; the result is checked to be in the working mode (same IK
    /// roots and same sign of det J as home), so a far-off start cannot silently return
    /// another assembly mode: it returns an error and the caller can use [`Self::fk_cold`].
    pub fn fk_from(&self, theta: &[f64; 3], r0: &Matrix3<f64>) -> Result<FkSolution> {
        let mut r = *r0;
        for it in 0..FK_MAX_ITER {
            let f = self.constraints(&r, theta);
            let res = f.amax();
            let j = self.constraint_jacobian(&r, theta);
            if res < FK_TOL {
                self.check_mode(&r, theta, &j)?;
                return Ok(FkSolution { r, iterations: it, residual: res });
            }
            let step = j.lu().solve(&(-f)).ok_or_else(|| {
                EyeError::FkFailed(format!("singular Jacobian at theta {:?} deg", theta.map(f64::to_degrees)))
            })?;
            if !step.iter().all(|x| x.is_finite()) || step.norm() > 1.0 {
                return Err(EyeError::FkFailed(format!(
                    "Newton step diverged at theta {:?} deg",
                    theta.map(f64::to_degrees)
                )));
            }
            r = exp_so3(&step) * r;
        }
        Err(EyeError::FkFailed(format!(
            "no convergence in {FK_MAX_ITER} iterations at theta {:?} deg",
            theta.map(f64::to_degrees)
        )))
    }

    fn check_mode(&self, r: &Matrix3<f64>, theta: &[f64; 3], j: &Matrix3<f64>) -> Result<()> {
        if j.determinant() * self.det_sign <= 0.0 {
            return Err(EyeError::FkFailed(format!(
                "solution at theta {:?} deg is another assembly mode",
                theta.map(f64::to_degrees)
            )));
        }
        for i in 0..3 {
            let (delta, gap) = self.leg_roots(i, r).ok_or_else(|| EyeError::FkFailed("leg open".into()))?;
            let mine = wrap(delta + self.branch[i] * gap - theta[i]).abs();
            let other = wrap(delta - self.branch[i] * gap - theta[i]).abs();
            if mine > other && gap > 1e-6 {
                return Err(EyeError::FkFailed(format!(
                    "leg {} on the other working mode at theta {:?} deg",
                    i + 1,
                    theta.map(f64::to_degrees)
                )));
            }
        }
        Ok(())
    }

    /// Cold-start FK: follows the straight path from home (theta = 0, R near identity) to
    /// `theta`, warm-starting Newton at each step, so the result is by construction the
    /// working-mode branch continuous with home. Refuses (error) if the path passes near a
    /// singularity, never returning another branch.
    pub fn fk_cold(&self, theta: &[f64; 3]) -> Result<FkSolution> {
        let mut r = self.fk_from(&[0.0; 3], &Matrix3::identity())?.r;
        let span = theta.iter().fold(0.0f64, |m, t| m.max(t.abs()));
        let mut n = ((span / 8f64.to_radians()).ceil() as usize).max(1);
        let mut s_done = 0.0;
        let mut total_it = 0;
        while s_done < 1.0 {
            let s = (s_done + 1.0 / n as f64).min(1.0);
            let th = [theta[0] * s, theta[1] * s, theta[2] * s];
            match self.fk_from(&th, &r) {
                Ok(sol) => {
                    self.check_regular(&sol.r, &th)?;
                    r = sol.r;
                    total_it += sol.iterations;
                    s_done = s;
                }
                Err(e) if n < 4096 => {
                    let _ = e;
                    n *= 2; // smaller steps from the last good point
                }
                Err(e) => return Err(e),
            }
        }
        let res = self.constraints(&r, theta).amax();
        Ok(FkSolution { r, iterations: total_it, residual: res })
    }
}

/// Wraps an angle (rad) to (-pi, pi].
#[inline]
pub fn wrap(a: f64) -> f64 {
    let mut x = a % (2.0 * PI);
    if x <= -PI {
        x += 2.0 * PI;
    } else if x > PI {
        x -= 2.0 * PI;
    }
    x
}

/// A stateful FK for streams (one per eye): warm-starts from the previous solution and
/// falls back to the cold start after a large jump or a failure.
#[derive(Debug, Clone)]
pub struct FkSolver {
    pub geom: SpmGeometry,
    last: Option<([f64; 3], Matrix3<f64>)>,
    /// Largest link-angle change (rad) accepted for a warm start.
    pub max_warm_jump: f64,
}

impl FkSolver {
    pub fn new(geom: SpmGeometry) -> Self {
        FkSolver { geom, last: None, max_warm_jump: 10f64.to_radians() }
    }
    pub fn reset(&mut self) {
        self.last = None;
    }
    pub fn solve(&mut self, theta: &[f64; 3]) -> Result<Matrix3<f64>> {
        let sol = match self.last {
            Some((t0, r0)) if (0..3).all(|i| (theta[i] - t0[i]).abs() <= self.max_warm_jump) => {
                match self.geom.fk_from(theta, &r0) {
                    Ok(s) => s,
                    Err(_) => self.geom.fk_cold(theta)?,
                }
            }
            _ => self.geom.fk_cold(theta)?,
        };
        self.last = Some((*theta, sol.r));
        Ok(sol.r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn deg3(a: [f64; 3]) -> [f64; 3] {
        a.map(f64::to_radians)
    }

    #[test]
    fn home_is_zero() {
        let g = SpmGeometry::nominal();
        let th = g.ik(&Matrix3::identity()).unwrap();
        assert!(th.iter().all(|t| t.abs() < 1e-14), "{th:?}");
        assert!(g.constraints(&Matrix3::identity(), &[0.0; 3]).amax() < 1e-15);
    }

    #[test]
    fn equal_links_are_pure_roll() {
        let g = SpmGeometry::nominal();
        for t in [-40.0, -15.0, 5.0, 15.0, 33.0] {
            let sol = g.fk_cold(&deg3([t, t, t])).unwrap();
            let f = Fick::from_matrix(&sol.r).to_deg();
            assert!(f[0].abs() < 1e-10 && f[2].abs() < 1e-10, "{f:?}");
            assert!((f[1] - t).abs() < 1e-10, "{f:?} for roll {t}");
            let back = g.ik(&Fick::from_deg([0.0, t, 0.0]).to_matrix()).unwrap();
            for b in back {
                assert!((b.to_degrees() - t).abs() < 1e-10);
            }
        }
    }

    /// A geometry off the nominal one by a few tenths of a degree (link angles, axes).
    fn perturbed() -> SpmGeometry {
        SpmGeometry::from_params(&[
            LegParams { d1_deg: 60.3, axis_tilt_deg: [0.2, -0.1], ..LegParams::nominal(0) },
            LegParams { d2_deg: 89.6, platform_axis_deg: [0.3, 0.2], ..LegParams::nominal(1) },
            LegParams::nominal(2),
        ])
    }

    #[test]
    fn constraint_jacobian_matches_finite_difference() {
        let g = perturbed();
        let r = Fick::from_deg([12.0, -7.0, 21.0]).to_matrix();
        let th = deg3([10.0, -20.0, 5.0]);
        let j = g.constraint_jacobian(&r, &th);
        let h = 1e-7;
        for k in 0..3 {
            let mut d = Vector3::zeros();
            d[k] = h;
            let fp = g.constraints(&(exp_so3(&d) * r), &th);
            let fm = g.constraints(&(exp_so3(&(-d)) * r), &th);
            let col = (fp - fm) / (2.0 * h);
            assert!((col - j.column(k)).amax() < 1e-8, "col {k}: {col} vs {}", j.column(k));
        }
        let jin = g.input_jacobian(&r, &th);
        for k in 0..3 {
            let mut tp = th;
            let mut tm = th;
            tp[k] += h;
            tm[k] -= h;
            let d = (g.constraints(&r, &tp)[k] - g.constraints(&r, &tm)[k]) / (2.0 * h);
            assert!((d - jin[k]).abs() < 1e-8);
        }
    }

    #[test]
    fn fk_jacobian_matches_finite_difference() {
        let g = SpmGeometry::nominal();
        let th = deg3([14.0, -9.0, 25.0]);
        let r = g.fk_cold(&th).unwrap().r;
        let jf = g.fk_jacobian(&r, &th).unwrap();
        let h = 1e-6;
        for k in 0..3 {
            let mut tp = th;
            let mut tm = th;
            tp[k] += h;
            tm[k] -= h;
            let rp = g.fk_from(&tp, &r).unwrap().r;
            let rm = g.fk_from(&tm, &r).unwrap().r;
            let w = crate::pose::rotation_vector(&(rp * rm.transpose())) / (2.0 * h);
            assert!((w - jf.column(k)).amax() < 1e-7, "col {k}: {w} vs {}", jf.column(k));
        }
    }

    #[test]
    fn warm_start_far_away_never_returns_wrong_mode_silently() {
        let g = SpmGeometry::nominal();
        let th = g.ik(&Fick::from_deg([25.0, -10.0, -28.0]).to_matrix()).unwrap();
        let truth = g.fk_cold(&th).unwrap().r;
        // A start on the far side of the sphere: either converges to the truth or errors.
        for start in [[170.0, 0.0, 0.0], [0.0, 170.0, 0.0], [80.0, 80.0, 80.0], [-60.0, 100.0, 10.0]] {
            let r0 = Fick::from_deg(start).to_matrix();
            if let Ok(sol) = g.fk_from(&th, &r0) {
                assert!((sol.r - truth).amax() < 1e-9, "silent wrong branch from {start:?}");
            }
        }
    }

    #[test]
    fn singularity_margin_over_workspace() {
        let g = SpmGeometry::nominal();
        let (mut par, mut ser) = (1.0f64, 1.0f64);
        for a in crate::psc::grid(-30.0, 30.0, 3.0) {
            for b in crate::psc::grid(-15.0, 15.0, 3.0) {
                for c in crate::psc::grid(-30.0, 30.0, 3.0) {
                    let r = Fick::from_deg([a, b, c]).to_matrix();
                    let s = g.singularity(&r, &g.ik(&r).unwrap());
                    par = par.min(s.parallel);
                    ser = ser.min(s.serial);
                }
            }
        }
        assert!(par > 0.2 && ser > 0.85, "parallel {par}, serial {ser}");
        assert!(par > 3.0 * DEFAULT_SINGULAR_LIMIT);
    }

    /// The closed form's extremes are the iterative eigen-decomposition's, and the fast check's verdict is the
    /// exact one's: over the workspace and beyond it (towards the singular tilts), on a perturbed geometry,
    /// and with the limit set at each configuration's own conditioning (the exact check then decides).
    #[test]
    fn the_fast_check_is_the_exact_check() {
        let g = perturbed();
        let (mut passed, mut refused, mut near) = (0, 0, 0);
        for a in crate::psc::grid(-80.0, 80.0, 8.0) {
            for b in crate::psc::grid(-40.0, 40.0, 8.0) {
                for c in crate::psc::grid(-80.0, 80.0, 8.0) {
                    let r = Fick::from_deg([a, b, c]).to_matrix();
                    let Ok(th) = g.ik(&r) else { continue };
                    let j = g.constraint_jacobian(&r, &th);
                    let m = j.tr_mul(&j);
                    let (lo, hi) = sym3_eigen_extremes(&m).unwrap();
                    let ev = m.symmetric_eigenvalues();
                    assert!((lo - ev.min()).abs() <= 1e-9 * ev.max() && (hi - ev.max()).abs() <= 1e-9 * ev.max());
                    let exact = g.check_singularity(&r, &th).is_ok();
                    assert_eq!(g.check_regular(&r, &th).is_ok(), exact, "Fick ({a}, {b}, {c})");
                    if exact {
                        passed += 1;
                    } else {
                        refused += 1;
                    }
                    // the limit at this configuration's own measure, and just above it
                    let s = g.singularity(&r, &th);
                    for lim in [s.measure(), s.measure() * (1.0 + 1e-12)] {
                        let at = SpmGeometry { singular_limit: lim, ..g.clone() };
                        assert_eq!(at.check_regular(&r, &th).is_ok(), at.check_singularity(&r, &th).is_ok());
                        near += 1;
                    }
                }
            }
        }
        assert!(passed > 500 && refused > 20 && near > 1000, "{passed} passed, {refused} refused, {near} near");
        // a multiple of the identity, and a singular matrix with a double root
        assert_eq!(sym3_eigen_extremes(&(Matrix3::identity() * 2.0)), Some((2.0, 2.0)));
        let (lo, hi) = sym3_eigen_extremes(&Matrix3::new(1.0, 1.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0)).unwrap();
        // a double root: the arccos's error, within the margin check_regular leaves
        assert!(lo.abs() < 1e-7 && (hi - 2.0).abs() < 1e-12, "{lo} {hi}");
    }

    #[test]
    fn refuses_near_singular() {
        let g = SpmGeometry::nominal();
        // Tilting the platform towards 90 deg drives a leg to full stretch.
        let r = Fick::from_deg([85.0, 0.0, 0.0]).to_matrix();
        match g.ik_checked(&r) {
            Err(EyeError::NearSingular { .. }) | Err(EyeError::Unreachable(_)) => {}
            other => panic!("expected refusal, got {other:?}"),
        }
    }
}
