//! The rotation error fitted to one frame's vertical disparities, and the check of one frame.
use super::*;

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
    /// The frame's pipeline sequence number.
    pub seq: u64,
    /// The frame's instant (CLOCK_MONOTONIC ns).
    pub t_frame_ns: i64,
    /// Both eyes' link angles (deg).
    pub theta: [[f64; 3]; 2],
    /// Features matched between the rectified images.
    pub matches: usize,
    /// |vertical disparity| quantiles (px); NaN without matches.
    pub vertical_p50: f64,
    /// 95th percentile of the same (px).
    pub vertical_p95: f64,
    /// The relative rotation fitted to the matches, when there were enough.
    pub fit: Option<RotationFit>,
}

/// Quantile of sorted values (nearest rank); NaN when empty.
pub(super) fn quantile(sorted: &[f64], q: f64) -> f64 {
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
