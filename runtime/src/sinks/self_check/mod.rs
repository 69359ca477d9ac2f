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
//!
//! **Timing.** With the raw cameras ([`SelfCheckSink::with_timing`]) the log also records, per match, how its
//! vertical disparity depends on each eye's row timing (`timing`): what `abvs calib self-check` estimates the
//! encoder-to-camera offset and the readout from.
//!
//! By concern: `matching` (corners, band search, Lucas-Kanade), `fit` (the rotation fit and the check of
//! one frame), `summary` (the run's statistics, the log's frame records), `log_record` (the logs' records, written
//! and read), `timing` (the per-match timing evidence),
//! `worker` (the sink and its thread).
use std::io::Write;
use std::path::PathBuf;
use std::thread::JoinHandle;

use crossbeam_channel::{bounded, Receiver, Sender};
use nalgebra::{Matrix3, Vector3};
use serde_json::{json, Value};

use abvs_runtime_core::error::{Result, RuntimeError};
use abvs_runtime_core::messages::{Published, Rectification, RectifiedCamera};
use abvs_runtime_core::sink::Sink;
use abvs_runtime_core::stats::{Latency, RunStats};

mod fit;
pub mod log_record;
mod matching;
mod summary;
mod timing;
mod worker;

pub use fit::*;
pub use matching::*;
pub use summary::*;
pub use timing::*;
pub use worker::*;

/// A run identity for the logs: 48 bits (exact in a CSV number) of SHA-256 over the run's configuration, the
/// wall-clock time and the process.
pub fn new_run_id(config: &str) -> u64 {
    use sha2::Digest;
    let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos());
    let mut h = sha2::Sha256::new();
    h.update(config.as_bytes());
    h.update(now.to_le_bytes());
    h.update(std::process::id().to_le_bytes());
    let d = h.finalize();
    d[..6].iter().fold(0u64, |a, b| (a << 8) | *b as u64).max(1)
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

    /// A pair wider than MATCH_WIDTH_MAX is matched box-filtered and its matches come back in its own
    /// pixels: a known sub-pixel shift of a 640 px texture reads the same as at 320.
    #[test]
    fn a_wide_pair_is_matched_at_a_coarser_level_in_its_own_pixels() {
        let tex = |x: f64, y: f64| {
            (128.0
                + 50.0 * (0.19 * x + 0.05 * y).sin()
                + 40.0 * (0.11 * y - 0.08 * x).cos()
                + 20.0 * (0.26 * x + 0.2 * y).sin())
            .clamp(1.0, 255.0)
        };
        let (w, h) = (640usize, 480usize);
        let (sx, sy) = (-15.3, 0.6);
        let left: Vec<u8> = (0..w * h).map(|i| tex((i % w) as f64, (i / w) as f64).round() as u8).collect();
        let right: Vec<u8> = (0..w * h).map(|i| tex((i % w) as f64 - sx, (i / w) as f64 - sy).round() as u8).collect();
        let mut matcher = Matcher::new(300, 4.0).unwrap();
        let mut out = Vec::new();
        matcher.find(&left, &right, w, h, 40.0, &mut out).unwrap();
        assert!(out.len() > 50, "{} matches", out.len());
        let med = |v: &mut Vec<f32>| {
            v.sort_by(f32::total_cmp);
            v[v.len() / 2]
        };
        let dx = med(&mut out.iter().map(|m| m.xr - m.xl).collect());
        let dy = med(&mut out.iter().map(|m| m.dy()).collect());
        // 0.05 px of the matched (half) level, as Lucas-Kanade's test at its own level; this texture's highest
        // frequency is 0.5 rad/px there, where bilinear sampling pulls a 0.3 px shift by ~0.03 px (read 0.067)
        assert!((dx - sx as f32).abs() < 0.1 && (dy - sy as f32).abs() < 0.1, "dx {dx} dy {dy}");
        assert!(out.iter().all(|m| m.xl > 0.0 && m.xl < w as f32 && m.yl < h as f32), "in the pair's pixels");
        assert!(out.iter().any(|m| m.xl > 400.0), "the whole width");
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
