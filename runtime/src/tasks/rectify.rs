//! Rectification every frame: the eyes move, so the extrinsic and with it the rectifying rotations change at
//! every frame. One remap per eye goes from the raw wide-angle image straight to the network's resolution
//! (undistort + rectify + resize in one map).
//!
//! The maps are built exactly (lens model of abvs-camera) on a coarse grid of nodes every `grid_step` output
//! pixels and interpolated in between (separable Catmull-Rom): the lens mapping is smooth, so this costs a few percent of
//! the exact build at a sub-0.01 px error (measured by `map_error_vs_exact` in the tests and benches).
//! Remapping is OpenCV's `remap` (bilinear); output pixels whose source lies outside the raw image are black
//! and marked invalid.
use abvs_camera::Camera;
use abvs_eye::Pose;
use nalgebra::{Matrix3, Vector2, Vector3};
use opencv::core::{Mat, Scalar, BORDER_CONSTANT};
use opencv::imgproc;
use opencv::prelude::*;

use crate::tasks::motion::RowRotations;
use abvs_runtime_core::error::{Result, RuntimeError};
use abvs_runtime_core::messages::Work;
use abvs_runtime_core::stage::{Stage, StageContext};

use abvs_runtime_core::messages::{Rectification, RectifiedCamera};

/// Rectifying rotations for the extrinsic `left_to_right` (x_r = R x_l + t): the rectified x axis runs along
/// the baseline from the left to the right centre (so disparity x_l - x_r is positive), z is the mean of the
/// two optical axes made orthogonal to it, y = z x x (down, as in OpenCV).
#[allow(clippy::neg_cmp_op_on_partial_ord)] // a NaN baseline is degenerate too
pub fn rectify(left_to_right: &Pose) -> Result<Rectification> {
    let r = left_to_right.r;
    let c = -(r.transpose() * left_to_right.t); // right centre in the left frame
    let baseline_m = c.norm();
    if !(baseline_m > 1e-6) {
        return Err(RuntimeError::Invalid(format!("stereo baseline {baseline_m} m is degenerate")));
    }
    let e1 = c / baseline_m;
    let z_mean = Vector3::z() + r.transpose() * Vector3::z();
    let e2 = z_mean.cross(&e1);
    if e2.norm() < 1e-6 {
        return Err(RuntimeError::Invalid("optical axes parallel to the baseline".into()));
    }
    let e2 = e2.normalize();
    let e3 = e1.cross(&e2);
    let rect_from_left = Matrix3::from_rows(&[e1.transpose(), e2.transpose(), e3.transpose()]);
    Ok(Rectification { rect_from_left, rect_from_right: rect_from_left * r.transpose(), baseline_m })
}

/// Source pixel in the raw image of rectified pixel (u, v) through `cam_from_rect`, exactly; with `rows`,
/// through the rotation of the raw row the pixel lands on (rolling shutter, [`crate::tasks::motion`]).
pub fn source_pixel(
    cam: &Camera,
    out: &RectifiedCamera,
    cam_from_rect: &Matrix3<f64>,
    rows: Option<&RowRotations>,
    u: f64,
    v: f64,
) -> Option<Vector2<f64>> {
    source_pixel_steps(cam, out, cam_from_rect, rows, u, v, ROW_STEPS)
}

/// Fixed-point steps of the raw row a rectified pixel lands on, from the frame's rotation. Each step shrinks
/// the error by the image's motion over the readout against the rows it spans, which a roll makes large at
/// the periphery. Measured at 640x480, 30 ms readout, a skew axis (test below): one step leaves 0.02 / 0.23
/// / 1.9 px at 30 / 100 / 300 deg/s, two 0.0002 / 0.006 / 0.16 px, three 0.014 px at 300. Two serve the
/// speeds the correction is for: at 4 ms exposure the blur gate stops frames above about 220 deg/s.
const ROW_STEPS: usize = 2;

fn source_pixel_steps(
    cam: &Camera,
    out: &RectifiedCamera,
    cam_from_rect: &Matrix3<f64>,
    rows: Option<&RowRotations>,
    u: f64,
    v: f64,
    steps: usize,
) -> Option<Vector2<f64>> {
    let ray = cam_from_rect * Vector3::new((u - out.cx) / out.f, (v - out.cy) / out.f, 1.0);
    let mut p = cam.project(&ray)?;
    if let Some(rows) = rows {
        for _ in 0..steps {
            p = cam.project(&(rows.at_row(p.y) * ray))?;
        }
    }
    Some(p)
}

/// Per-eye remap tables, allocated once and rebuilt in place every frame.
pub struct RectifyMaps {
    /// The rectified camera the maps produce.
    pub out: RectifiedCamera,
    /// Node spacing of the map grid (px).
    pub grid_step: u32,
    map_x: Mat,
    map_y: Mat,
    /// Exact source pixels at the grid nodes (x, y); NaN where the ray leaves the lens model.
    nodes: Vec<[f32; 2]>,
    /// Nodes interpolated along x: one row per node row, one entry per output column.
    rows: Vec<[f32; 2]>,
    /// The rolling-shutter correction (per-row source minus global-shutter source) at every
    /// [`ROW_DELTA_STRIDE`]-th node, interpolated to the others.
    delta: Vec<[f32; 2]>,
    nodes_w: usize,
    nodes_h: usize,
}

/// Node stride of the rolling-shutter correction: it is exact every this many nodes (16 px at the default
/// 8 px grid) and bilinear in between, a smooth field (a rotation that varies along the rows) on top of
/// the exact global map. It costs a quarter of the extra lens projections of an exact per-row map; at
/// 100 deg/s the map's 99th-percentile error against the exact per-row one is 0.007 px (0.0004 exact at
/// every node), its worst 0.067 px on the last rows (test below).
const ROW_DELTA_STRIDE: usize = 2;

fn delta_dims(nodes_w: usize, nodes_h: usize) -> (usize, usize) {
    ((nodes_w - 1).div_ceil(ROW_DELTA_STRIDE) + 1, (nodes_h - 1).div_ceil(ROW_DELTA_STRIDE) + 1)
}

impl RectifyMaps {
    /// Maps for `out`, exact at grid nodes `grid_step` px apart.
    pub fn new(out: RectifiedCamera, grid_step: u32) -> Result<Self> {
        let cv = |e: opencv::Error| RuntimeError::Invalid(format!("rectify: {}", e.message));
        let (w, h) = (out.width as i32, out.height as i32);
        let step = grid_step.max(1);
        let nodes_w = (out.width as usize - 1).div_ceil(step as usize) + 4;
        let nodes_h = (out.height as usize - 1).div_ceil(step as usize) + 4;
        Ok(RectifyMaps {
            out,
            grid_step: step,
            map_x: Mat::new_rows_cols_with_default(h, w, opencv::core::CV_32FC1, Scalar::all(-1.0)).map_err(cv)?,
            map_y: Mat::new_rows_cols_with_default(h, w, opencv::core::CV_32FC1, Scalar::all(-1.0)).map_err(cv)?,
            nodes: vec![[f32::NAN; 2]; nodes_w * nodes_h],
            rows: vec![[f32::NAN; 2]; nodes_h * out.width as usize],
            delta: vec![
                [f32::NAN; 2];
                {
                    let (dw, dh) = delta_dims(nodes_w, nodes_h);
                    dw * dh
                }
            ],
            nodes_w,
            nodes_h,
        })
    }

    /// Rebuilds the map of one eye for the rotation `rect_from_cam`: exact lens projection at the grid nodes,
    /// separable Catmull-Rom interpolation in between (bilinear would err by ~0.2 px at 8 px spacing on a
    /// 118 deg fisheye; the cubic stays under 0.01 px).
    pub fn build(&mut self, cam: &Camera, rect_from_cam: &Matrix3<f64>) {
        self.build_rows(cam, rect_from_cam, None)
    }

    /// As [`RectifyMaps::build`], each raw row seen through its own rotation (`rows`: the camera when that
    /// row exposed, from the virtual camera `rect_from_cam` refers to); `None` is a global shutter.
    pub fn build_rows(&mut self, cam: &Camera, rect_from_cam: &Matrix3<f64>, rows: Option<&RowRotations>) {
        let cam_from_rect = rect_from_cam.transpose();
        let out = self.out;
        let step = self.grid_step as usize;
        // node (i, j) sits at output pixel ((i - 1) * step, (j - 1) * step): one node before the image and two
        // past its end give every pixel the four-node support of the cubic.
        let at = |i: usize| (i as f64 - 1.0) * step as f64;
        let px = |p: Option<Vector2<f64>>| p.map_or([f32::NAN; 2], |p| [p.x as f32, p.y as f32]);
        for j in 0..self.nodes_h {
            for i in 0..self.nodes_w {
                self.nodes[j * self.nodes_w + i] = px(source_pixel(cam, &out, &cam_from_rect, None, at(i), at(j)));
            }
        }
        if let Some(rows) = rows {
            self.add_row_correction(cam, &cam_from_rect, rows);
        }
        let (w, h) = (out.width as usize, out.height as usize);
        let inv = 1.0 / step as f32;
        // pass 1: along x for every node row
        for j in 0..self.nodes_h {
            let row = &self.nodes[j * self.nodes_w..(j + 1) * self.nodes_w];
            for x in 0..w {
                let g = x as f32 * inv;
                let i0 = g as usize;
                let wts = catmull_rom(g - i0 as f32);
                let mut acc = [0f32; 2];
                for (k, wt) in wts.iter().enumerate() {
                    let n = row[i0 + k];
                    acc[0] += wt * n[0];
                    acc[1] += wt * n[1];
                }
                self.rows[j * w + x] = acc;
            }
        }
        // pass 2: along y
        // Bilinear sampling reads (x+1, y+1): a source is valid when both neighbours are inside the raw image.
        let (maxx, maxy) = (cam.width as f32 - 2.0, cam.height as f32 - 2.0);
        let mx = self.map_x.data_typed_mut::<f32>().expect("CV_32FC1 map");
        let my = self.map_y.data_typed_mut::<f32>().expect("CV_32FC1 map");
        for y in 0..h {
            let g = y as f32 * inv;
            let j0 = g as usize;
            let wts = catmull_rom(g - j0 as f32);
            for x in 0..w {
                let mut acc = [0f32; 2];
                for (k, wt) in wts.iter().enumerate() {
                    let n = self.rows[(j0 + k) * w + x];
                    acc[0] += wt * n[0];
                    acc[1] += wt * n[1];
                }
                let (sx, sy) = (acc[0], acc[1]);
                // NaN (outside the lens model) and sources off the raw image both become "invalid" (-1).
                let inside = sx >= 0.0 && sy >= 0.0 && sx <= maxx && sy <= maxy;
                mx[y * w + x] = if inside { sx } else { -1.0 };
                my[y * w + x] = if inside { sy } else { -1.0 };
            }
        }
    }

    /// Moves the global-shutter nodes to their per-row sources: exact every [`ROW_DELTA_STRIDE`] nodes,
    /// bilinear in between; a node whose surrounding corrections are not all known is computed exactly.
    fn add_row_correction(&mut self, cam: &Camera, cam_from_rect: &Matrix3<f64>, rows: &RowRotations) {
        let (out, step, nw, nh) = (self.out, self.grid_step as f64, self.nodes_w, self.nodes_h);
        let (dw, dh) = delta_dims(nw, nh);
        let exact = |i: usize, j: usize| {
            let (u, v) = ((i as f64 - 1.0) * step, (j as f64 - 1.0) * step);
            source_pixel(cam, &out, cam_from_rect, Some(rows), u, v).map(|p| [p.x as f32, p.y as f32])
        };
        for cj in 0..dh {
            let j = (cj * ROW_DELTA_STRIDE).min(nh - 1);
            for ci in 0..dw {
                let i = (ci * ROW_DELTA_STRIDE).min(nw - 1);
                let g = self.nodes[j * nw + i];
                self.delta[cj * dw + ci] = match exact(i, j) {
                    Some(p) => [p[0] - g[0], p[1] - g[1]],
                    None => [f32::NAN; 2],
                };
            }
        }
        let (delta, nodes) = (&self.delta, &mut self.nodes);
        for j in 0..nh {
            let cj = (j / ROW_DELTA_STRIDE).min(dh - 2);
            // the last coarse row/column sits at the last node, not a stride past the one before it
            let span_j = ((cj + 1) * ROW_DELTA_STRIDE).min(nh - 1) - cj * ROW_DELTA_STRIDE;
            let tj = (j - cj * ROW_DELTA_STRIDE) as f32 / span_j as f32;
            for i in 0..nw {
                let n = &mut nodes[j * nw + i];
                if !n[0].is_finite() {
                    continue;
                }
                let ci = (i / ROW_DELTA_STRIDE).min(dw - 2);
                let span_i = ((ci + 1) * ROW_DELTA_STRIDE).min(nw - 1) - ci * ROW_DELTA_STRIDE;
                let ti = (i - ci * ROW_DELTA_STRIDE) as f32 / span_i as f32;
                let d = |a: usize, b: usize| delta[(cj + b) * dw + ci + a];
                let (d00, d10, d01, d11) = (d(0, 0), d(1, 0), d(0, 1), d(1, 1));
                let known = [d00, d10, d01, d11].iter().all(|x| x[0].is_finite());
                *n = if known {
                    let lerp = |k: usize| {
                        let top = d00[k] + (d10[k] - d00[k]) * ti;
                        let bottom = d01[k] + (d11[k] - d01[k]) * ti;
                        n[k] + top + (bottom - top) * tj
                    };
                    [lerp(0), lerp(1)]
                } else {
                    exact(i, j).unwrap_or([f32::NAN; 2])
                };
            }
        }
    }

    /// Largest distance (px, in the raw image) between the interpolated map and the exact one, over all
    /// output pixels whose exact source is inside the raw image.
    pub fn map_error_vs_exact(&self, cam: &Camera, rect_from_cam: &Matrix3<f64>) -> f64 {
        self.map_error_vs_exact_rows(cam, rect_from_cam, None)
    }

    /// [`RectifyMaps::map_error_vs_exact`] for a map built with per-row rotations.
    pub fn map_error_vs_exact_rows(
        &self,
        cam: &Camera,
        rect_from_cam: &Matrix3<f64>,
        rows: Option<&RowRotations>,
    ) -> f64 {
        let cam_from_rect = rect_from_cam.transpose();
        let mx = self.map_x.data_typed::<f32>().expect("map");
        let my = self.map_y.data_typed::<f32>().expect("map");
        let w = self.out.width as usize;
        let mut worst: f64 = 0.0;
        for y in 0..self.out.height as usize {
            for x in 0..w {
                if mx[y * w + x] < 0.0 {
                    continue;
                }
                if let Some(p) = source_pixel(cam, &self.out, &cam_from_rect, rows, x as f64, y as f64) {
                    worst = worst.max((p - Vector2::new(mx[y * w + x] as f64, my[y * w + x] as f64)).norm());
                }
            }
        }
        worst
    }

    /// Whether output pixel `i` (row-major) has a source inside the raw image.
    #[inline]
    pub fn valid(&self, i: usize) -> bool {
        self.map_x.data_typed::<f32>().map(|m| m[i] >= 0.0).unwrap_or(false)
    }

    /// The source x of every rectified pixel (row-major; negative where it sees no raw pixel).
    pub fn map_x(&self) -> &[f32] {
        self.map_x.data_typed::<f32>().expect("map")
    }

    /// Remaps a raw 8-bit gray image (`raw_w` x `raw_h`) into `out` (the output size), bilinear.
    pub fn remap(&self, raw: &[u8], raw_w: u32, raw_h: u32, out: &mut [u8]) -> Result<()> {
        let cv = |e: opencv::Error| RuntimeError::Invalid(format!("remap: {}", e.message));
        if raw.len() != (raw_w * raw_h) as usize || out.len() != (self.out.width * self.out.height) as usize {
            return Err(RuntimeError::Invalid(format!(
                "remap: image of {} bytes for {raw_w}x{raw_h}, output of {} bytes for {}x{}",
                raw.len(),
                out.len(),
                self.out.width,
                self.out.height
            )));
        }
        let src = Mat::new_rows_cols_with_data(raw_h as i32, raw_w as i32, raw).map_err(cv)?;
        let mut dst =
            Mat::new_rows_cols_with_data_mut(self.out.height as i32, self.out.width as i32, out).map_err(cv)?;
        imgproc::remap(
            &src,
            &mut dst,
            &self.map_x,
            &self.map_y,
            imgproc::INTER_LINEAR,
            BORDER_CONSTANT,
            Scalar::all(0.0),
        )
        .map_err(cv)
    }
}

/// Catmull-Rom weights of the four nodes around a point at fraction `t` between the middle two.
#[inline]
fn catmull_rom(t: f32) -> [f32; 4] {
    let (t2, t3) = (t * t, t * t * t);
    [0.5 * (-t3 + 2.0 * t2 - t), 0.5 * (3.0 * t3 - 5.0 * t2 + 2.0), 0.5 * (-3.0 * t3 + 4.0 * t2 + t), 0.5 * (t3 - t2)]
}

/// Both eyes' maps and the current rectification.
pub struct StereoRectifier {
    /// The left eye's maps.
    pub left: RectifyMaps,
    /// The right eye's maps.
    pub right: RectifyMaps,
    /// The left eye's lens.
    pub cam_left: Camera,
    /// The right eye's lens.
    pub cam_right: Camera,
}

impl StereoRectifier {
    /// Maps for both eyes' lenses into `out`.
    pub fn new(cam_left: Camera, cam_right: Camera, out: RectifiedCamera, grid_step: u32) -> Result<Self> {
        Ok(StereoRectifier {
            left: RectifyMaps::new(out, grid_step)?,
            right: RectifyMaps::new(out, grid_step)?,
            cam_left,
            cam_right,
        })
    }

    /// Rectifying rotations for the extrinsic of this frame, and both maps rebuilt for them.
    pub fn update(&mut self, left_to_right: &Pose) -> Result<Rectification> {
        self.update_rows(left_to_right, [None, None])
    }

    /// As [`StereoRectifier::update`], each eye's rows through their own rotations (rolling shutter).
    pub fn update_rows(&mut self, left_to_right: &Pose, rows: [Option<RowRotations>; 2]) -> Result<Rectification> {
        let rect = rectify(left_to_right)?;
        self.left.build_rows(&self.cam_left, &rect.rect_from_left, rows[0].as_ref());
        self.right.build_rows(&self.cam_right, &rect.rect_from_right, rows[1].as_ref());
        Ok(rect)
    }
}

/// Scales calibration intrinsics to the frames' size (sensor binning modes keep the lens).
pub fn camera_for_frames(cam: &Camera, w: u32, h: u32) -> Result<Camera> {
    if cam.width == w && cam.height == h {
        return Ok(*cam);
    }
    let ra = cam.width as f64 / cam.height as f64;
    let rb = w as f64 / h as f64;
    if (ra - rb).abs() > 1e-3 {
        return Err(RuntimeError::Invalid(format!(
            "calibration is for {}x{} images, the frames are {w}x{h} (different aspect ratio)",
            cam.width, cam.height
        )));
    }
    Ok(cam.scaled(w, h))
}

/// The rectification stage: per-frame maps for the moving extrinsic and the remapped pair
/// ([`Work::rectified`]).
pub struct RectifyStage {
    /// Both eyes' lenses as calibrated (scaled to the frames' size at the start).
    pub cams: (Camera, Camera),
    /// Node spacing of the map grid (px).
    pub grid_step: u32,
    rectifier: Option<StereoRectifier>,
}

impl RectifyStage {
    /// The stage for both eyes' lenses (left, right); its maps are made at start, at the graph's output.
    pub fn new(cams: (Camera, Camera), grid_step: u32) -> Self {
        RectifyStage { cams, grid_step, rectifier: None }
    }
}

impl Stage for RectifyStage {
    fn name(&self) -> &'static str {
        "rectify"
    }

    fn start(&mut self, ctx: &mut StageContext) -> Result<()> {
        let (rw, rh) = ctx.raw;
        let cam_l = camera_for_frames(&self.cams.0, rw, rh)?;
        let cam_r = camera_for_frames(&self.cams.1, rw, rh)?;
        let mut rectifier = StereoRectifier::new(cam_l, cam_r, ctx.out, self.grid_step)?;
        // One remap here, on the runner's thread: OpenCV's worker threads (remap's, and SGBM_3WAY's in the
        // disparity lane) start now with its priority, not later from this lane's, which steps back
        // (runner.rs, step_back_priority) and would hand its lower priority to every worker.
        rectifier.left.build(&cam_l, &Matrix3::identity());
        let raw = vec![0u8; (rw * rh) as usize];
        let mut out = vec![0u8; (ctx.out.width * ctx.out.height) as usize];
        rectifier.left.remap(&raw, rw, rh, &mut out)?;
        self.rectifier = Some(rectifier);
        Ok(())
    }

    fn process(&mut self, w: &mut Work) -> Result<()> {
        let rectifier = self.rectifier.as_mut().ok_or_else(|| RuntimeError::Invalid("rectify: not started".into()))?;
        let pose = w.pose.as_ref().ok_or_else(|| RuntimeError::Invalid("rectify: a frame without pose".into()))?;
        let raw_h = rectifier.cam_left.height;
        let rows = |eye: usize| {
            let nodes = &w.motion.band_rot[eye];
            (!nodes.is_empty()).then_some(RowRotations { nodes, rows: raw_h })
        };
        let rect = rectifier.update_rows(&pose.left_to_right, [rows(0), rows(1)])?;
        let (rw, rh) = (rectifier.cam_left.width, rectifier.cam_left.height);
        let out = &mut w.rectified;
        rectifier.left.remap(&w.raw_left, rw, rh, &mut out.left)?;
        rectifier.right.remap(&w.raw_right, rw, rh, &mut out.right)?;
        for (v, x) in out.valid.iter_mut().zip(rectifier.left.map_x()) {
            *v = (*x >= 0.0) as u8;
        }
        out.rect = Some(rect);
        Ok(())
    }

    fn failure(&self, e: &RuntimeError) -> &'static str {
        abvs_runtime_core::stage::timing_failure(e).unwrap_or("kinematics or rectification failed")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use abvs_eye::Fick;

    #[test]
    fn rectified_rays_of_a_point_share_a_row_and_disparity_is_positive() {
        let e = Pose::new(Fick::from_deg([1.5, -2.0, 4.0]).to_matrix(), Vector3::new(-0.064, 0.002, 0.003));
        let rect = rectify(&e).unwrap();
        for p_l in [Vector3::new(0.1, 0.05, 0.5), Vector3::new(-0.3, 0.2, 1.4), Vector3::new(0.0, 0.0, 0.25)] {
            let p_r = e.r * p_l + e.t;
            let a = rect.rect_from_left * p_l;
            let b = rect.rect_from_right * p_r;
            // same y/z ratio (same row), x_l > x_r (positive disparity), depth from disparity is exact
            assert!((a.y / a.z - b.y / b.z).abs() < 1e-12);
            assert!((a.z - b.z).abs() < 1e-12);
            let d = a.x / a.z - b.x / b.z;
            assert!(d > 0.0);
            assert!((rect.baseline_m / d - a.z).abs() < 1e-9);
        }
    }

    #[test]
    fn coarse_grid_map_is_within_a_hundredth_of_a_pixel() {
        let cam = Camera::ov8856().scaled(800, 600);
        let out = RectifiedCamera::with_hfov(320, 240, 100.0);
        let e = Pose::new(Fick::from_deg([10.0, 5.0, -20.0]).to_matrix(), Vector3::new(-0.065, 0.0, 0.0));
        let rect = rectify(&e).unwrap();
        let mut maps = RectifyMaps::new(out, 8).unwrap();
        maps.build(&cam, &rect.rect_from_left);
        let err = maps.map_error_vs_exact(&cam, &rect.rect_from_left);
        assert!(err < 0.01, "grid map error {err} px");
        let mut exact = RectifyMaps::new(out, 1).unwrap();
        exact.build(&cam, &rect.rect_from_left);
        assert!(exact.map_error_vs_exact(&cam, &rect.rect_from_left) < 1e-3);
    }

    /// Row rotations of a 30 ms readout in 8 bands, the eye turning at 100 deg/s about a skew axis (yaw,
    /// pitch and roll).
    fn pursuit_rows_100_deg_s() -> Vec<Matrix3<f64>> {
        let axis = Vector3::new(0.8, 0.5, 0.33).normalize();
        (0..=8)
            .map(|b| {
                let t = (b as f64 / 8.0 - 0.5) * 0.030;
                *nalgebra::Rotation3::from_scaled_axis(axis * 100f64.to_radians() * t).matrix()
            })
            .collect()
    }

    #[test]
    fn the_row_steps_are_within_a_hundredth_of_a_pixel_of_the_fixed_point_up_to_100_deg_s() {
        let cam = Camera::ov8856().scaled(640, 480);
        let out = RectifiedCamera::with_hfov(640, 480, 100.0);
        let nodes = pursuit_rows_100_deg_s();
        let rows = RowRotations { nodes: &nodes, rows: 480 };
        let cam_from_rect = Fick::from_deg([8.0, -5.0, 3.0]).to_matrix();
        let (mut worst, mut moved) = (0f64, 0f64);
        for v in (0..480).step_by(12) {
            for u in (0..640).step_by(16) {
                let (u, v) = (u as f64, v as f64);
                let (Some(one), Some(fixed), Some(global)) = (
                    source_pixel_steps(&cam, &out, &cam_from_rect, Some(&rows), u, v, ROW_STEPS),
                    source_pixel_steps(&cam, &out, &cam_from_rect, Some(&rows), u, v, 20),
                    source_pixel_steps(&cam, &out, &cam_from_rect, None, u, v, 0),
                ) else {
                    continue;
                };
                worst = worst.max((one - fixed).norm());
                moved = moved.max((fixed - global).norm());
            }
        }
        // the correction itself moves sources by several pixels here (8.4 px): the test is not vacuous
        assert!(moved > 5.0, "rolling shutter moves sources by {moved} px");
        assert!(worst < 0.01, "{ROW_STEPS} steps leave {worst} px");
    }

    #[test]
    fn the_per_row_map_matches_the_exact_one_at_100_deg_s() {
        let cam = Camera::ov8856().scaled(800, 600);
        let out = RectifiedCamera::with_hfov(640, 480, 100.0);
        let e = Pose::new(Fick::from_deg([10.0, 5.0, -20.0]).to_matrix(), Vector3::new(-0.065, 0.0, 0.0));
        let rect = rectify(&e).unwrap();
        let nodes = pursuit_rows_100_deg_s();
        let rows = RowRotations { nodes: &nodes, rows: 600 };
        let mut maps = RectifyMaps::new(out, 8).unwrap();
        maps.build_rows(&cam, &rect.rect_from_left, Some(&rows));
        // per pixel against the exact per-row source: the 99th percentile is what matching sees; the worst
        // is on the last rows, where the row rotations stop at the image's edge (a kink the bilinear
        // correction rounds off; an exact per-row map at every node: p99 0.0004, worst 0.016 px)
        let cam_from_rect = rect.rect_from_left.transpose();
        let (mx, my) = (maps.map_x(), maps.map_y.data_typed::<f32>().unwrap());
        let mut errs: Vec<f64> = (0..640 * 480)
            .filter(|i| mx[*i] >= 0.0)
            .filter_map(|i| {
                let p = source_pixel(&cam, &out, &cam_from_rect, Some(&rows), (i % 640) as f64, (i / 640) as f64)?;
                Some((p - Vector2::new(mx[i] as f64, my[i] as f64)).norm())
            })
            .collect();
        errs.sort_by(f64::total_cmp);
        let (p99, worst) = (errs[errs.len() * 99 / 100], errs[errs.len() - 1]);
        assert!(p99 < 0.01 && worst < 0.1, "per-row map error p99 {p99} px, worst {worst} px");
        // and it is a different map from the global shutter's: the correction is there
        let mut global = RectifyMaps::new(out, 8).unwrap();
        global.build(&cam, &rect.rect_from_left);
        let moved = maps.map_x().iter().zip(global.map_x()).filter(|(a, b)| **a >= 0.0 && **b >= 0.0);
        let moved = moved.map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        assert!(moved > 3.0, "the correction moves sources by {moved} px");
    }

    #[test]
    fn remap_of_a_constant_image_is_constant_inside_and_black_outside() {
        let cam = Camera::ov8856().scaled(400, 300);
        let out = RectifiedCamera::with_hfov(160, 120, 140.0);
        let mut maps = RectifyMaps::new(out, 8).unwrap();
        maps.build(&cam, &Matrix3::identity());
        let raw = vec![200u8; 400 * 300];
        let mut o = vec![0u8; 160 * 120];
        maps.remap(&raw, 400, 300, &mut o).unwrap();
        let (mut inside, mut outside) = (0, 0);
        for (i, v) in o.iter().enumerate() {
            if maps.valid(i) {
                inside += 1;
                assert!(*v >= 199, "pixel {i}: {v}");
            } else {
                outside += 1;
                assert_eq!(*v, 0);
            }
        }
        assert!(inside > 0 && outside > 0, "140 deg output reaches beyond the raw image's corners");
        assert!(maps.remap(&raw[1..], 400, 300, &mut o).is_err());
    }
}
