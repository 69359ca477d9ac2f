//! Timing evidence: how each match's vertical disparity would move if an eye's rows were stamped wrong.
//!
//! The runtime reads each row's pose from the encoders at the time it believes the row exposed
//! (conventions.md "Time"). If that time is wrong by `eps` (used - true) the row is rectified with the eye's
//! pose `R exp([omega eps]x)` instead of `R` (`omega`: the eye's angular velocity in its own frame), so the
//! rectified camera's true orientation is off by `a = -rect_from_cam omega eps` (rectified frame). A scene
//! point `P` (rectified left frame, from the match's disparity) is then imaged moved by `-a x P`, left and
//! right each by their own `a`: the vertical disparity changes by `s_l eps_l + s_r eps_r`. This holds both the
//! relative rotation (what the self-check's rotation fit sees, driven by the eyes' *difference* of velocity:
//! vergence) and the common one (a rotation of both cameras tilts the baseline in the images, a vertical
//! disparity proportional to the disparity: driven by conjugate pursuit).
//!
//! With an encoder-to-camera offset wrong by `dT` per eye and a readout wrong by `dR`, row fraction `rho`
//! (0 = top row, of the raw image) has `eps = dT + dR (rho - anchor)`; `anchor` is the row the stamps fix
//! ([`abvs_runtime_core::messages::SourcePair::readout_anchor`]). `abvs calib self-check` fits `dT` and `dR` per eye to
//! the logged matches; this module only measures, per match, the raw rows and `s_l`, `s_r`.
use super::log_record::MatchRecord;
use super::*;
use abvs_camera::Camera;

use crate::tasks::motion::RowRotations;
use crate::tasks::rectify::source_pixel;

/// What the timing evidence needs beyond a rectified pair: the raw cameras (at the frames' size) and the
/// time offsets the run applies, written to the log so the estimate can say what to change them to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimingContext {
    /// Left and right raw cameras, scaled to the frames.
    pub cams: [Camera; 2],
    /// encoder_time_offset each eye's encoders are read with (ms).
    pub time_offset_ms: [f64; 2],
}

/// One match's timing evidence.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchTiming {
    /// Raw row of the left and the right point, as a fraction of the image (0 = top, 1 = bottom).
    pub row: [f64; 2],
    /// Change of the vertical disparity (px) per millisecond of the left and the right eye's time error.
    pub px_per_ms: [f64; 2],
    /// Change of the vertical disparity (px) per millisecond that each camera's optical centre moves at its
    /// velocity. The per-row correction turns rows but does not move them (`tasks::motion`), so a row read
    /// `dt` from the frame's instant keeps this parallax, `u dt`, even with the timing right: the fit
    /// subtracts it rather than reading it as readout.
    pub translation_px_per_ms: [f64; 2],
}

/// Vertical image motion (px) of a point at `p` (camera frame) when the camera turns by `a` (rad), to first
/// order: the point's coordinates become `p - a x p`.
fn dy_px(f: f64, p: &Vector3<f64>, a: &Vector3<f64>) -> f64 {
    let dp = -a.cross(p);
    f * (dp.y * p.z - p.y * dp.z) / (p.z * p.z)
}

/// Vertical image motion (px) of a point at `p` (camera frame) when the camera's centre moves by `c`.
fn dy_translation_px(f: f64, p: &Vector3<f64>, c: &Vector3<f64>) -> f64 {
    let q = p - c;
    f * (q.y / q.z - p.y / p.z)
}

/// The timing evidence of match `m` of the checked pair `job`; `None` where a point leaves a raw image or
/// the disparity is too small to place it.
pub fn match_timing(m: &Match, job: &Job, ctx: &TimingContext) -> Option<MatchTiming> {
    let cam = &job.cam;
    let rect = &job.rect;
    let d = (m.xl - m.xr) as f64;
    if d < 0.5 {
        return None;
    }
    let mut row = [0.0; 2];
    for (eye, (u, v)) in [(m.xl as f64, m.yl as f64), (m.xr as f64, m.yr as f64)].into_iter().enumerate() {
        let rect_from_cam = if eye == 0 { rect.rect_from_left } else { rect.rect_from_right };
        let raw = &ctx.cams[eye];
        let nodes = &job.band_rot[eye];
        let rows = (!nodes.is_empty()).then_some(RowRotations { nodes, rows: raw.height });
        let p = source_pixel(raw, cam, &rect_from_cam.transpose(), rows.as_ref(), u, v)?;
        row[eye] = p.y / (raw.height.max(2) - 1) as f64;
    }
    let z = cam.f * rect.baseline_m / d;
    let p = Vector3::new((m.xl as f64 - cam.cx) / cam.f * z, (m.yl as f64 - cam.cy) / cam.f * z, z);
    let q = p - Vector3::new(rect.baseline_m, 0.0, 0.0);
    let a_l = -(rect.rect_from_left * job.omega_rad_s[0]) * 1e-3;
    let a_r = -(rect.rect_from_right * job.omega_rad_s[1]) * 1e-3;
    let c_l = rect.rect_from_left * job.vel_m_s[0] * 1e-3;
    let c_r = rect.rect_from_right * job.vel_m_s[1] * 1e-3;
    Some(MatchTiming {
        row,
        px_per_ms: [-dy_px(cam.f, &p, &a_l), dy_px(cam.f, &q, &a_r)],
        translation_px_per_ms: [-dy_translation_px(cam.f, &p, &c_l), dy_translation_px(cam.f, &q, &c_r)],
    })
}

/// The match log's record of a match (`j`: the match's design row for the rotation error, px/rad).
pub(super) fn match_record(seq: u64, m: &Match, t: &MatchTiming, j: &Vector3<f64>, run_id: u64) -> MatchRecord {
    MatchRecord {
        seq,
        xl: m.xl as f64,
        yl: m.yl as f64,
        xr: m.xr as f64,
        yr: m.yr as f64,
        row_l: t.row[0],
        row_r: t.row[1],
        dy_px: m.dy() as f64,
        j_x: j.x,
        j_y: j.y,
        j_z: j.z,
        s_l_px_per_ms: t.px_per_ms[0],
        s_r_px_per_ms: t.px_per_ms[1],
        u_l_px_per_ms: t.translation_px_per_ms[0],
        u_r_px_per_ms: t.translation_px_per_ms[1],
        run_id: Some(run_id),
    }
}
