//! Depth and point cloud from disparity.
//!
//! Depth is Z in the rectified left camera frame (Z = f B / d); it is range-limited (default 0.2-1.6 m, the eyes'
//! working range) and every pixel without a valid depth is NaN, never 0. Points are expressed in the **left
//! home camera frame** (metres, OpenCV axes), the frame that does not move with the eyes:
//! p_home = T_rel,l . R_rect_l^T . p_rect. Buffers are allocated once; `compute` does not allocate.
use abvs_eye::Pose;
use glam::{Mat3, Vec3};

use abvs_runtime_core::error::{Result, RuntimeError};
use abvs_runtime_core::messages::{CloudPoint, DepthFrame};
use abvs_runtime_core::messages::{Rectification, RectifiedCamera, Work};
use abvs_runtime_core::stage::{Stage, StageContext};

/// The depth range kept: points nearer or farther are invalid (NaN, not in the cloud).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthConfig {
    /// Nearest depth kept (m).
    pub min_m: f32,
    /// Farthest depth kept (m).
    pub max_m: f32,
}

impl Default for DepthConfig {
    fn default() -> Self {
        DepthConfig { min_m: 0.2, max_m: 1.6 }
    }
}

/// Fills `out`'s depth and points from a disparity map; `valid` says which rectified pixels see the raw image.
// the negated comparisons reject NaN disparities and depths too
#[allow(clippy::too_many_arguments, clippy::neg_cmp_op_on_partial_ord, clippy::nonminimal_bool)]
pub fn compute(
    out: &mut DepthFrame,
    disparity: &[f32],
    valid: impl Fn(usize) -> bool,
    left_rect: &[u8],
    cam: &RectifiedCamera,
    rect: &Rectification,
    rel_left: &Pose,
    cfg: &DepthConfig,
) {
    let fb = (cam.f * rect.baseline_m) as f32;
    // rectified -> current left camera -> left home camera
    let m = rel_left.r * rect.rect_from_left.transpose();
    let rot = Mat3::from_cols_array(&[
        m[(0, 0)] as f32,
        m[(1, 0)] as f32,
        m[(2, 0)] as f32,
        m[(0, 1)] as f32,
        m[(1, 1)] as f32,
        m[(2, 1)] as f32,
        m[(0, 2)] as f32,
        m[(1, 2)] as f32,
        m[(2, 2)] as f32,
    ]);
    let t = Vec3::new(rel_left.t.x as f32, rel_left.t.y as f32, rel_left.t.z as f32);
    let (w, h) = (out.width as usize, out.height as usize);
    let (inv_f, cx, cy) = (1.0 / cam.f as f32, cam.cx as f32, cam.cy as f32);
    let mut n = 0;
    // the slices taken once: the map and the cloud may be in messages' lent buffers (`LentMap`)
    let DepthFrame { depth, cloud, pixel, .. } = out;
    let (depth, cloud) = (&mut depth[..], &mut cloud[..]);
    for v in 0..h {
        for u in 0..w {
            let i = v * w + u;
            let d = disparity[i];
            let z = fb / d;
            if !(d > 0.0) || !(z >= cfg.min_m && z <= cfg.max_m) || !valid(i) {
                depth[i] = f32::NAN;
                continue;
            }
            depth[i] = z;
            let p = Vec3::new((u as f32 - cx) * inv_f * z, (v as f32 - cy) * inv_f * z, z);
            cloud[n] = CloudPoint::new(rot * p + t, left_rect[i]);
            pixel[n] = i as u32;
            n += 1;
        }
    }
    out.n_points = n;
}

/// The depth stage: depth map and cloud ([`Work::depth`]) from the disparity, on the output lane (which
/// lends the frame its depth buffer).
pub struct DepthStage {
    /// The depth range.
    pub cfg: DepthConfig,
    cam: Option<RectifiedCamera>,
    /// Frames published invalid by the motion gate.
    gated: u64,
}

impl DepthStage {
    /// A depth stage keeping `cfg`'s range.
    pub fn new(cfg: DepthConfig) -> Self {
        DepthStage { cfg, cam: None, gated: 0 }
    }
}

impl Stage for DepthStage {
    fn name(&self) -> &'static str {
        "depth"
    }

    fn start(&mut self, ctx: &mut StageContext) -> Result<()> {
        self.cam = Some(ctx.out);
        Ok(())
    }

    fn process(&mut self, w: &mut Work) -> Result<()> {
        let cam = self.cam.as_ref().ok_or_else(|| RuntimeError::Invalid("depth: not started".into()))?;
        let Work { disparity, rectified, pose, depth, motion, .. } = w;
        let (Some(pose), Some(rect)) = (pose.as_ref(), rectified.rect.as_ref()) else {
            return Err(RuntimeError::Invalid("depth: a frame without pose or rectification".into()));
        };
        if depth.depth.len() != disparity.len() {
            return Err(RuntimeError::Invalid("depth: no depth buffer (the stage runs on the output lane)".into()));
        }
        if motion.gated {
            // too blurred to match: published, but never as valid depth (NaN, empty cloud, flagged)
            depth.depth.fill(f32::NAN);
            depth.n_points = 0;
            self.gated += 1;
            return Ok(());
        }
        let valid = &rectified.valid;
        compute(depth, disparity, |i| valid[i] != 0, &rectified.left, cam, rect, &pose.rel_left, &self.cfg);
        Ok(())
    }

    fn finish(&mut self, stats: &mut abvs_runtime_core::stats::RunStats) {
        stats.frames_motion_gated += self.gated;
    }

    fn failure(&self, _e: &RuntimeError) -> &'static str {
        "depth failed"
    }

    fn needs_output_lane(&self) -> bool {
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tasks::rectify::rectify;
    use nalgebra::Vector3;

    #[test]
    fn a_fronto_parallel_plane_comes_back_at_its_depth_in_the_home_frame() {
        let cam = RectifiedCamera::with_hfov(64, 48, 90.0);
        let e = Pose::new(nalgebra::Matrix3::identity(), Vector3::new(-0.065, 0.0, 0.0));
        let rect = rectify(&e).unwrap();
        let z = 0.8f32;
        let d = (cam.f * rect.baseline_m) as f32 / z;
        let disp = vec![d; 64 * 48];
        let mut f = DepthFrame::new(64, 48);
        let rel = Pose::new(nalgebra::Matrix3::identity(), Vector3::new(0.001, 0.0, 0.0));
        compute(&mut f, &disp, |i| i != 5, &[7u8; 64 * 48], &cam, &rect, &rel, &DepthConfig::default());
        assert_eq!(f.n_points, 64 * 48 - 1);
        assert!(f.depth[5].is_nan());
        for p in &f.cloud[..f.n_points] {
            assert!((p.z - z).abs() < 1e-5);
        }
        assert!((f.cloud[0].x - ((0.0 - cam.cx as f32) / cam.f as f32 * z + 0.001)).abs() < 1e-5);
        assert_eq!(f.cloud[0].gray(), 7);
        // out of range and invalid disparities are NaN, not zero
        let far = vec![0.5f32; 64 * 48];
        compute(&mut f, &far, |_| true, &[0u8; 64 * 48], &cam, &rect, &rel, &DepthConfig::default());
        assert_eq!(f.n_points, 0);
        assert!(f.depth.iter().all(|d| d.is_nan()));
    }
}
