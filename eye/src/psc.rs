//! Pose sensitivity coefficient (the paper's eq. 8-10):
//! `S(theta) = max_i || r(theta + d e_i) - r(theta) || / d`, with `r` the rotation vector (rad)
//! of the orientation, `d = 1 deg` and S in rad per degree. S is lowest near the centre of the
//! workspace; M4 splits the workspace by it.
use crate::error::Result;
use crate::pose::{rotation_vector, Fick};
use crate::spm::SpmGeometry;
use nalgebra::Matrix3;

/// The paper's finite step, degrees.
pub const PSC_STEP_DEG: f64 = 1.0;

/// S at link angles `theta` (rad) for the geometry's FK, warm-started from `r` = FK(theta).
pub fn psc_at(geom: &SpmGeometry, theta: &[f64; 3], r: &Matrix3<f64>) -> Result<f64> {
    let d = PSC_STEP_DEG.to_radians();
    let r0 = rotation_vector(r);
    let mut s: f64 = 0.0;
    for i in 0..3 {
        let mut t = *theta;
        t[i] += d;
        let ri = geom.fk_from(&t, r)?.r;
        s = s.max((rotation_vector(&ri) - r0).norm());
    }
    Ok(s / PSC_STEP_DEG)
}

/// First-order S from the analytic FK Jacobian, for the per-frame hot path: `||J_r^-1(r) omega_i||`
/// per degree, with `omega_i` the angular-velocity Jacobian column and `J_r^-1` the inverse left
/// Jacobian of SO(3) mapping it to rotation-vector rates. It differs from [`psc_at`] by the
/// curvature over the 1 deg step (a few 1e-4 over the workspace); callers that need the exact
/// value near a threshold use [`psc_at`] there.
pub fn psc_first_order(geom: &SpmGeometry, theta: &[f64; 3], r: &Matrix3<f64>) -> Result<f64> {
    let jf = geom.fk_jacobian(r, theta)?;
    let rv = rotation_vector(r);
    let th = rv.norm();
    let k = crate::pose::skew(&rv);
    let jl_inv = if th < 1e-8 {
        Matrix3::identity() - 0.5 * k
    } else {
        Matrix3::identity() - 0.5 * k + (1.0 / (th * th) - (1.0 + th.cos()) / (2.0 * th * th.sin())) * k * k
    };
    let m = jl_inv * jf;
    let s = (0..3).map(|i| m.column(i).norm()).fold(0.0, f64::max);
    Ok(s * PSC_STEP_DEG.to_radians() / PSC_STEP_DEG)
}

/// S at link angles `theta` (rad), solving the FK from cold.
pub fn psc(geom: &SpmGeometry, theta: &[f64; 3]) -> Result<f64> {
    let r = geom.fk_cold(theta)?.r;
    psc_at(geom, theta, &r)
}

/// One cell of the workspace map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PscPoint {
    /// Commanded Fick angles, degrees.
    pub fick_deg: [f64; 3],
    /// Link angles from the IK, degrees.
    pub theta_deg: [f64; 3],
    pub s: f64,
}

/// S over the Fick grid alpha in [-30, 30], beta in [-15, 15], gamma in [-30, 30] at `step_deg`.
/// Grid poses that are unreachable or near-singular for this geometry are left out.
pub fn psc_map(geom: &SpmGeometry, step_deg: f64) -> Vec<PscPoint> {
    let [la, lb, lg] = crate::WORKSPACE_DEG;
    let mut out = Vec::new();
    for a in grid(-la, la, step_deg) {
        for b in grid(-lb, lb, step_deg) {
            for g in grid(-lg, lg, step_deg) {
                let r = Fick::from_deg([a, b, g]).to_matrix();
                let Ok(th) = geom.ik_checked(&r) else {
                    continue;
                };
                if let Ok(s) = psc_at(geom, &th, &r) {
                    out.push(PscPoint { fick_deg: [a, b, g], theta_deg: th.map(f64::to_degrees), s });
                }
            }
        }
    }
    out
}

/// Values `lo, lo + step, ..., hi` (hi included when on the grid), robust to float drift.
pub fn grid(lo: f64, hi: f64, step: f64) -> Vec<f64> {
    let n = ((hi - lo) / step + 1e-9).floor() as i64;
    (0..=n).map(|k| lo + k as f64 * step).collect()
}

/// Value below which a fraction `q` (0..1) of the map lies.
pub fn percentile(values: &[f64], q: f64) -> f64 {
    let mut v: Vec<f64> = values.to_vec();
    v.sort_by(|a, b| a.total_cmp(b));
    if v.is_empty() {
        return f64::NAN;
    }
    let idx = ((v.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize;
    v[idx]
}

/// The spread of S over a map (rad/deg): NaN for an empty map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PscSpread {
    /// Smallest S.
    pub min: f64,
    /// 10th percentile.
    pub p10: f64,
    /// Median.
    pub median: f64,
    /// 90th percentile.
    pub p90: f64,
    /// Largest S.
    pub max: f64,
}

/// Min, p10, median, p90 and max of S over `map`.
pub fn spread(map: &[PscPoint]) -> PscSpread {
    let s: Vec<f64> = map.iter().map(|p| p.s).collect();
    let q = |q: f64| percentile(&s, q);
    PscSpread { min: q(0.0), p10: q(0.1), median: q(0.5), p90: q(0.9), max: q(1.0) }
}

/// Writes `map` as CSV: alpha_deg, beta_deg, gamma_deg, theta1_deg..theta3_deg, psc.
pub fn write_csv(map: &[PscPoint], path: &std::path::Path) -> Result<()> {
    let err = |e: csv::Error| crate::error::EyeError::file(path, None, format!("cannot create: {e}"));
    let mut w = csv::Writer::from_path(path).map_err(err)?;
    w.write_record(["alpha_deg", "beta_deg", "gamma_deg", "theta1_deg", "theta2_deg", "theta3_deg", "psc"])
        .map_err(err)?;
    for p in map {
        let mut rec: Vec<String> = p.fick_deg.iter().chain(&p.theta_deg).map(|x| format!("{x}")).collect();
        rec.push(format!("{}", p.s));
        w.write_record(&rec).map_err(err)?;
    }
    w.flush().map_err(|e| crate::error::EyeError::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_map_is_written_as_csv_and_spread_by_percentiles() {
        let map = psc_map(&SpmGeometry::nominal(), 15.0);
        let sp = spread(&map);
        assert!(sp.min <= sp.p10 && sp.p10 <= sp.median && sp.median <= sp.p90 && sp.p90 <= sp.max, "{sp:?}");
        assert!(spread(&[]).median.is_nan());
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("psc.csv");
        write_csv(&map, &p).unwrap();
        let text = std::fs::read_to_string(&p).unwrap();
        assert_eq!(text.lines().count(), map.len() + 1);
        assert!(text.starts_with("alpha_deg,beta_deg,gamma_deg,theta1_deg,theta2_deg,theta3_deg,psc\n"));
        assert!(write_csv(&map, &dir.path().join("no/such/dir.csv")).is_err());
    }

    #[test]
    fn psc_lowest_near_centre() {
        let g = SpmGeometry::nominal();
        let centre = psc(&g, &[0.0; 3]).unwrap();
        let map = psc_map(&g, 10.0);
        let max = map.iter().map(|p| p.s).fold(0.0, f64::max);
        assert!(map.iter().all(|p| p.s.is_finite() && p.s > 0.0));
        assert!(max > centre, "edge {max} vs centre {centre}");
        // Pure roll of 1 deg is 0.01745 rad; a single link moves the platform more than that.
        assert!(centre > 1f64.to_radians() * 0.5 && centre < 0.2, "{centre}");
    }

    #[test]
    fn first_order_psc_is_close_to_the_finite_step() {
        let g = SpmGeometry::nominal();
        let mut worst: f64 = 0.0;
        for p in psc_map(&g, 6.0) {
            let th = p.theta_deg.map(f64::to_radians);
            let r = g.fk_cold(&th).unwrap().r;
            worst = worst.max((psc_first_order(&g, &th, &r).unwrap() - p.s).abs());
        }
        assert!(worst < 1e-3, "{worst}");
    }

    #[test]
    fn grid_counts() {
        assert_eq!(grid(-30.0, 30.0, 1.0).len(), 61);
        assert_eq!(grid(-15.0, 15.0, 3.0).len(), 11);
        assert_eq!(grid(-30.0, 30.0, 3.0).len(), 21);
    }
}
