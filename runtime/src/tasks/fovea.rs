//! The fovea: depth at the source frames' native scale where the eyes look.
//!
//! Every frame, after the main map's disparity, the stage takes the fixation point from the frame's poses
//! (encoders and calibrated FK: [`measured_fixation`], the closest approach of both optical axes, the gaze
//! stage's measure). When that point is in front and between [`FoveaConfig::min_distance_m`] and
//! [`FoveaConfig::max_distance_m`] the window is centred on it; otherwise on the rectified image centre at
//! [`FoveaConfig::default_distance_m`]. The window (default 320x240) is a crop of the main map's rectified
//! plane at the raw frames' focal length (the main map is that plane at the processing resolution), remapped
//! from the raw frames with the rectify stage's maps and the frame's per-row rotations (rolling shutter).
//!
//! The search is narrow: the main map's disparities over the window (5th to 95th percentile, scaled to the
//! fovea and widened by a margin) or, where the main map has too few there, the fixation's disparity
//! +- half the range. The right window's principal point is moved by the range's start, so that SGBM searches
//! `[0, range)` without losing the window's left columns to a large disparity. SGBM_3WAY (the runtime's own
//! engine at 5x5 blocks) matches the pair. A window pixel it leaves without an answer, or whose answer leaves
//! the main map's by more than two main-map pixels, takes the main map's (nearest main pixel, scaled), and a
//! pixel the main map's validity mask rejected has no depth: the fovea has the main map's valid pixels over
//! its window, refined, never contradicted (the stats JSON's `fovea.filled_from_main_fraction`,
//! `overruled_by_main_fraction` and `masked_by_main_fraction` say how often). The depth stage's arithmetic
//! makes depth and cloud. A frame the
//! motion gate stopped publishes an invalid fovea (NaN, empty cloud) and costs no match.
use abvs_camera::Camera;
use abvs_eye::Pose;
use nalgebra::Vector3;

use crate::gaze::stage::measured_fixation;
use crate::tasks::depth::DepthConfig;
use abvs_disparity::fovea::{main_histogram, search_range, FoveaMatcher, MainAt, HIST_BINS_PER_PX};

use crate::tasks::disparity::runtime_error;
use crate::tasks::motion::RowRotations;
use crate::tasks::rectify::{camera_for_frames, RectifyMaps};
use abvs_runtime_core::error::{Result, RuntimeError};
use abvs_runtime_core::messages::{FoveaFrame, RectifiedCamera, Work};
use abvs_runtime_core::params::FoveaConfig;
use abvs_runtime_core::stage::{Stage, StageContext};

/// The fovea stage (see the module doc). Runs on a lane of its own between disparity and output.
pub struct FoveaStage {
    cfg: FoveaConfig,
    depth: DepthConfig,
    cams: (Camera, Camera),
    grid_step: u32,
    home_left_to_right: Pose,
    started: Option<Started>,
    counts: Counts,
}

struct Started {
    cam_l: Camera,
    cam_r: Camera,
    main: RectifiedCamera,
    focal: f64,
    maps: [RectifyMaps; 2],
    /// The matching core, shared with `abvs disparity-eval --fovea` (abvs_disparity::fovea).
    matcher: FoveaMatcher,
    /// The pair at the matched width: the window plus `max_range_px` columns on its left, so that SGBM,
    /// which gives the first `range` columns no match, still answers the whole window.
    ext: (Vec<u8>, Vec<u8>),
    hist: Vec<u32>,
    /// The main map at each window pixel, scaled to the fovea.
    main_at: Vec<MainAt>,
}

#[derive(Default)]
struct Counts {
    frames: u64,
    measured: u64,
    from_main: u64,
    gated: u64,
    /// Frames passed on without a fovea because the lane was behind ([`Stage::shed`]).
    shed: u64,
    points: u64,
    /// Window pixels the narrow search left without an answer, given the main map's.
    filled_from_main: u64,
    /// Window pixels whose narrow-search answer left the main map's by more than its error.
    overruled_by_main: u64,
    /// Window pixels the main map's validity mask left without depth (its confidence below the threshold).
    masked_by_main: u64,
    range_sum: f64,
    cpu_ns: i64,
    wall_ns: i64,
}

impl FoveaStage {
    /// The stage for both eyes' lenses (as calibrated), the home extrinsic T_lH^rH (m), the rectify stage's
    /// map grid and the main map's depth range.
    pub fn new(
        cfg: FoveaConfig,
        cams: (Camera, Camera),
        home_left_to_right: Pose,
        grid_step: u32,
        depth: DepthConfig,
    ) -> Self {
        FoveaStage { cfg, depth, cams, grid_step, home_left_to_right, started: None, counts: Counts::default() }
    }
}

/// The window's intrinsics for a fixation at `p` (rectified left frame, m): `focal`, the fixation at the
/// window's centre.
pub fn window(width: u32, height: u32, focal: f64, p: &Vector3<f64>) -> RectifiedCamera {
    RectifiedCamera {
        width,
        height,
        f: focal,
        cx: (width as f64 - 1.0) / 2.0 - focal * p.x / p.z,
        cy: (height as f64 - 1.0) / 2.0 - focal * p.y / p.z,
    }
}

impl Stage for FoveaStage {
    fn name(&self) -> &'static str {
        "fovea"
    }

    fn prepare_work(&self, w: &mut Work) {
        w.fovea = Some(Box::new(FoveaFrame::new(self.cfg.width, self.cfg.height)));
    }

    fn start(&mut self, ctx: &mut StageContext) -> Result<()> {
        let c = &self.cfg;
        if !(16..=4096).contains(&c.width) || !(16..=4096).contains(&c.height) {
            return Err(RuntimeError::Invalid(format!("fovea: {}x{} is not a usable window", c.width, c.height)));
        }
        let (rw, rh) = ctx.raw;
        let cam_l = camera_for_frames(&self.cams.0, rw, rh)?;
        let cam_r = camera_for_frames(&self.cams.1, rw, rh)?;
        // the raw frames' focal length: native scale at the image centre
        let focal = (cam_l.fx + cam_l.fy + cam_r.fx + cam_r.fy) / 4.0;
        let ew = c.width + c.max_range_px;
        let out = RectifiedCamera::with_hfov(ew, c.height, 60.0);
        let maps = [RectifyMaps::new(out, self.grid_step)?, RectifyMaps::new(out, self.grid_step)?];
        let matcher = FoveaMatcher::new(c.width, c.height, c.max_range_px).map_err(runtime_error)?;
        let n = (ew * c.height) as usize;
        let ext = (vec![0u8; n], vec![0u8; n]);
        let hist_len = (ctx.out.width as f64 * HIST_BINS_PER_PX) as usize + 1;
        let main_at = vec![MainAt::Outside; (c.width * c.height) as usize];
        let hist = vec![0; hist_len];
        self.started = Some(Started { cam_l, cam_r, main: ctx.out, focal, maps, matcher, ext, hist, main_at });
        Ok(())
    }

    fn process(&mut self, w: &mut Work) -> Result<()> {
        let (cpu0, wall0) = (abvs_runtime_core::cpu::thread_cpu_ns(), abvs_runtime_core::messages::monotonic_ns());
        let s = self.started.as_mut().ok_or_else(|| RuntimeError::Invalid("fovea: not started".into()))?;
        let Work { fovea, pose, rectified, motion, disparity, raw_left, raw_right, .. } = w;
        let f =
            fovea.as_deref_mut().ok_or_else(|| RuntimeError::Invalid("fovea: a frame without its buffers".into()))?;
        let (Some(pose), Some(rect)) = (pose.as_ref(), rectified.rect.as_ref()) else {
            return Err(RuntimeError::Invalid("fovea: a frame without pose or rectification".into()));
        };
        let (cfg, dcfg) = (self.cfg, self.depth);
        // where the eyes look, in the rectified left frame
        let to_rect = rect.rect_from_left * pose.rel_left.r.transpose();
        let (p_home, dist) = measured_fixation(pose, &self.home_left_to_right);
        let p = to_rect * (Vector3::from(p_home) - pose.rel_left.t);
        #[allow(clippy::neg_cmp_op_on_partial_ord)] // NaN is not measured either
        let measured = dist >= cfg.min_distance_m && dist <= cfg.max_distance_m && p.z > 0.05;
        let (p, p_home) = if measured {
            (p, p_home)
        } else {
            let p = Vector3::new(0.0, 0.0, cfg.default_distance_m);
            let h = to_rect.transpose() * p + pose.rel_left.t;
            (p, [h.x, h.y, h.z])
        };
        let cam = window(cfg.width, cfg.height, s.focal, &p);
        let fb = s.focal * rect.baseline_m;
        let d_fix = fb / p.z;
        // the main map's disparities over the window
        let m = s.main;
        let scale = s.focal / m.f;
        let to_main = |u: f64, cf: f64, cm: f64| (u - cf) / scale + cm;
        let (u0, u1) = (to_main(0.0, cam.cx, m.cx).floor(), to_main(cam.width as f64 - 1.0, cam.cx, m.cx).ceil());
        let (v0, v1) = (to_main(0.0, cam.cy, m.cy).floor(), to_main(cam.height as f64 - 1.0, cam.cy, m.cy).ceil());
        let clampx = |x: f64, n: u32| x.clamp(0.0, n as f64 - 1.0) as usize;
        let (u0, u1, v0, v1) = (clampx(u0, m.width), clampx(u1, m.width), clampx(v0, m.height), clampx(v1, m.height));
        let n = main_histogram(disparity, m.width as usize, (u0, u1), (v0, v1), &mut s.hist);
        let window_px = (cam.width as f64 / scale) * (cam.height as f64 / scale);
        let lim = [fb / dcfg.min_m as f64, fb / dcfg.max_m as f64];
        let (start, range, from_main) = search_range(&s.hist, n, window_px, scale, d_fix, cfg.max_range_px, lim);
        f.cam = cam;
        f.offset_px = start;
        f.search_px = [start, start + range as f64];
        f.fixation_m = p_home;
        f.fixation_distance_m = if measured { dist } else { p.norm() };
        f.measured = measured;
        f.from_main = from_main;
        self.counts.frames += 1;
        self.counts.measured += measured as u64;
        if motion.gated {
            f.disparity.fill(f32::NAN);
            f.depth.depth.fill(f32::NAN);
            f.depth.n_points = 0;
            f.ready = true;
            self.counts.gated += 1;
            return Ok(());
        }
        self.counts.from_main += from_main as u64;
        self.counts.range_sum += range as f64;
        // both windows, each raw row through its own rotation (as the rectify stage does)
        let rows = |eye: usize| {
            let nodes = &motion.band_rot[eye];
            (!nodes.is_empty()).then_some(RowRotations { nodes, rows: s.cam_l.height })
        };
        // matched `pad` columns wider on the left (see `Started::ext`), then cropped to the window
        let pad = cfg.max_range_px as usize;
        let ext_cam = RectifiedCamera { width: cam.width + pad as u32, cx: cam.cx + pad as f64, ..cam };
        s.maps[0].out = ext_cam;
        s.maps[1].out = RectifiedCamera { cx: ext_cam.cx + start, ..ext_cam };
        s.maps[0].build_rows(&s.cam_l, &rect.rect_from_left, rows(0).as_ref());
        s.maps[1].build_rows(&s.cam_r, &rect.rect_from_right, rows(1).as_ref());
        let (rw, rh) = (s.cam_l.width, s.cam_l.height);
        let (el, er) = &mut s.ext;
        s.maps[0].remap(raw_left, rw, rh, el)?;
        s.maps[1].remap(raw_right, rw, rh, er)?;
        let (w, ew) = (cam.width as usize, ext_cam.width as usize);
        let map_x = s.maps[0].map_x();
        for v in 0..cam.height as usize {
            let (o, e) = (v * w..(v + 1) * w, v * ew + pad..(v + 1) * ew);
            f.left[o.clone()].copy_from_slice(&el[e.clone()]);
            f.right[o.clone()].copy_from_slice(&er[e.clone()]);
            for (val, x) in f.valid[o].iter_mut().zip(&map_x[e]) {
                *val = (*x >= 0.0) as u8;
            }
        }
        // The main map's answer at the nearest main pixel along the same ray, scaled to the fovea: the
        // refinement rule (abvs_disparity::fovea::refine) keeps it where the narrow search has none or leaves
        // it by more than the main map's own error, and gives no depth where the main map's validity mask
        // (`min_confidence`) has none. So the fovea publishes the main map's depths over its window,
        // refined, never contradicted.
        let mw = m.width as usize;
        for v in 0..cam.height as usize {
            let vm = to_main(v as f64, cam.cy, m.cy).round();
            let row = &mut s.main_at[v * w..(v + 1) * w];
            if !(0.0..m.height as f64).contains(&vm) {
                row.fill(MainAt::Outside);
                continue;
            }
            let base = vm as usize * mw;
            for (u, o) in row.iter_mut().enumerate() {
                let um = to_main(u as f64, cam.cx, m.cx).round();
                *o = if !(0.0..m.width as f64).contains(&um) {
                    MainAt::Outside
                } else {
                    let d = disparity[base + um as usize];
                    if d > 0.0 {
                        MainAt::Disparity((d as f64 * scale) as f32)
                    } else {
                        MainAt::Masked
                    }
                };
            }
        }
        let counts = s
            .matcher
            .fovea(el, er, (start, range), &f.valid, &s.main_at, scale, lim, &mut f.disparity)
            .map_err(runtime_error)?;
        let (filled, overruled, masked) = (counts.filled, counts.overruled, counts.masked);
        self.counts.overruled_by_main += overruled;
        self.counts.masked_by_main += masked;
        self.counts.filled_from_main += filled;
        let FoveaFrame { disparity, valid, left, depth, .. } = &mut *f;
        crate::tasks::depth::compute(depth, disparity, |i| valid[i] != 0, left, &cam, rect, &pose.rel_left, &dcfg);
        f.ready = true;
        self.counts.points += f.depth.n_points as u64;
        self.counts.cpu_ns += abvs_runtime_core::cpu::thread_cpu_ns() - cpu0;
        self.counts.wall_ns += abvs_runtime_core::messages::monotonic_ns() - wall0;
        Ok(())
    }

    fn failure(&self, e: &RuntimeError) -> &'static str {
        abvs_runtime_core::stage::timing_failure(e).unwrap_or("fovea failed")
    }

    /// Behind (a newer frame waits), the frame goes on without its fovea (`ready` stays false: no fovea is
    /// published for it) rather than holding up the lanes after it, whose queue would drop whole frames.
    /// On this 2-core VM the default run dropped 2-11 of the fixture's 50 frames with the fovea on and
    /// 0-1 with it off (runtime/BENCHMARKS.md, "The fovea under load").
    fn shed(&mut self, _w: &mut Work) -> bool {
        self.counts.shed += self.cfg.shed_when_behind as u64;
        self.cfg.shed_when_behind
    }

    fn finish(&mut self, stats: &mut abvs_runtime_core::stats::RunStats) {
        let c = &self.counts;
        let matched = (c.frames - c.gated).max(1) as f64;
        let focal = self.started.as_ref().map_or(f64::NAN, |s| s.focal);
        stats.extra.insert(
            "fovea".into(),
            serde_json::json!({
                "window": [self.cfg.width, self.cfg.height],
                "focal_px": focal,
                "frames": c.frames,
                "measured_fixation": c.measured,
                "range_from_main": c.from_main,
                "gated": c.gated,
                "shed_behind": c.shed,
                "mean_range_px": c.range_sum / matched,
                "mean_points": c.points as f64 / matched,
                "filled_from_main_fraction": c.filled_from_main as f64 / (matched * (self.cfg.width * self.cfg.height) as f64),
                "overruled_by_main_fraction": c.overruled_by_main as f64 / (matched * (self.cfg.width * self.cfg.height) as f64),
                "masked_by_main_fraction": c.masked_by_main as f64 / (matched * (self.cfg.width * self.cfg.height) as f64),
                "cpu_ms_per_frame": c.cpu_ns as f64 * 1e-6 / matched,
                "wall_ms_per_frame": c.wall_ns as f64 * 1e-6 / matched,
            }),
        );
    }
}
