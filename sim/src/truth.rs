//! Depth accuracy against ground truth, for synthetic sessions.
//!
//! For a published point at rectified pixel (u, v), the pipeline's own chain says which raw pixel it came
//! from (rectifying rotation, the per-row rotations of a rolling-shutter correction, lens); the truth says
//! where that raw pixel really looked: the true camera pose when its row exposed (true unit model at the
//! true link angles of that row's mid-exposure, `truth/row_poses.csv`; the frame's instant for a global
//! shutter) and a ray cast into the true scene. So a point placed with the wrong row's pose is scored by how
//! far from the true surface point it lands, not only along its ray. Errors compare the published
//! point with that true surface point: `abs_rel` = |r_est - r_true| / r_true (ranges from the true optical
//! centre) and `rmse_m` = RMS of the 3D distance. Points are scored on a fixed pixel stride (casting every
//! point would cost more than the pipeline). Frames are matched to their truth by `seq` (the first column of
//! the truth's poses file), never by position: a frame the replay could not read shifts nothing. When the run
//! computes a confidence, the points are also scored apart by it (above and at most [`HIGH_CONFIDENCE`]):
//! stats `depth_error_by_confidence`. Per eye speed (the faster eye at the frame's instant): stats
//! `depth_error_by_speed`, with the frames the motion gate published invalid counted, not scored. When the
//! engine masks its own pixels (census-refine), the map before the mask is scored too, every pixel the depth
//! range keeps: stats `depth_error_all_pixels`, beside `depth_error` over the published pixels.
use abvs_camera::{Camera, StereoCalibration};
use abvs_eye::{Pose, UnitModel};
use abvs_render::Scene;
use nalgebra::{Point3, UnitQuaternion, Vector2, Vector3};

use abvs_runtime::sources::replay::ReplaySource;
use abvs_runtime::tasks::depth::DepthConfig;
use abvs_runtime::tasks::motion::RowRotations;
use abvs_runtime::tasks::rectify::source_pixel;
use abvs_runtime_core::error::{Result, RuntimeError};
use abvs_runtime_core::messages::Published;
use abvs_runtime_core::messages::{DepthFrame, FoveaFrame};
use abvs_runtime_core::session::{Session, SessionMeta};
use abvs_runtime_core::sink::Sink;
use abvs_runtime_core::stats::{DepthError, RunStats};

/// The confidence above which a point counts as confident in `depth_error_by_confidence`.
pub const HIGH_CONFIDENCE: f32 = 0.8;

/// Lower edges of the eye-speed bands of `depth_error_by_speed` (deg/s, the faster eye at the frame's
/// instant): fixation, slow pursuit, fast pursuit, slow saccade, saccade.
pub const SPEED_BANDS_DEG_S: [f64; 5] = [0.0, 5.0, 30.0, 100.0, 300.0];

/// Bin width (mm) and range of the point-error histogram of a speed band: a soak scores frames for as long
/// as it runs, so the median comes from a fixed histogram, not from every distance kept.
const DIST_BIN_MM: f64 = 0.05;
const DIST_BINS: usize = 40_000; // 0 .. 2 m; farther lands in the last bin

/// The error of the frames of one speed band.
#[derive(Debug, Clone)]
pub struct SpeedBand {
    /// Frames scored (published with depth, a truth row for their seq).
    pub frames: u64,
    /// Frames the motion gate published invalid.
    pub gated: u64,
    pub abs_rel_sum: f64,
    pub points: u64,
    /// Histogram of each scored point's 3D distance to the true surface point ([`DIST_BIN_MM`] bins),
    /// allocated and written at start-up: its memory is resident from the first frame, not as the bins are
    /// first hit.
    dist_hist: Vec<u32>,
}

impl SpeedBand {
    fn new() -> Self {
        let mut dist_hist = Vec::with_capacity(DIST_BINS);
        // written, not calloc'ed (zero pages would become resident bin by bin over a soak); black_box: the
        // buffer escapes before it is written, so the write cannot be folded into a zeroed allocation
        std::hint::black_box(&mut dist_hist);
        dist_hist.resize(DIST_BINS, 0);
        SpeedBand { frames: 0, gated: 0, abs_rel_sum: 0.0, points: 0, dist_hist }
    }

    fn add_distance(&mut self, mm: f64) {
        let bin = ((mm / DIST_BIN_MM) as usize).min(DIST_BINS - 1);
        self.dist_hist[bin] = self.dist_hist[bin].saturating_add(1);
    }

    /// Median 3D point error (mm, to the histogram's 0.05 mm), NaN without points.
    pub fn point_mm_p50(&self) -> f64 {
        let n: u64 = self.dist_hist.iter().map(|&c| c as u64).sum();
        if n == 0 {
            return f64::NAN;
        }
        let (half, mut below) = (n as f64 / 2.0, 0u64);
        for (i, &c) in self.dist_hist.iter().enumerate() {
            let c = c as u64;
            if c > 0 && (below + c) as f64 >= half {
                // linear within the bin
                return (i as f64 + (half - below as f64) / c as f64) * DIST_BIN_MM;
            }
            below += c;
        }
        DIST_BINS as f64 * DIST_BIN_MM
    }

    pub fn abs_rel(&self) -> f64 {
        if self.points == 0 {
            f64::NAN
        } else {
            self.abs_rel_sum / self.points as f64
        }
    }
}

/// The band of a speed (deg/s).
pub fn speed_band(deg_s: f64) -> usize {
    SPEED_BANDS_DEG_S.iter().rposition(|lo| deg_s >= *lo).unwrap_or(0)
}

pub struct TruthSink {
    scene: Scene,
    camera: Camera,
    /// True T_rel of the left eye per session frame (metres), by seq (increasing), and at its row nodes
    /// (empty for a global shutter).
    poses: Vec<(u64, Pose, Vec<Pose>)>,
    stride: usize,
    err: DepthError,
    /// The same over the points of confidence above [`HIGH_CONFIDENCE`], and the others (runs with one).
    by_confidence: Option<[DepthError; 2]>,
    /// The same over every pixel of the map before the validity mask (runs whose engine masks its own
    /// pixels: [`Published::dense_disparity`]), and the depth range that map is cut to (the depth stage's).
    all_pixels: Option<DepthError>,
    range: DepthConfig,
    /// That map's depth and points (reused).
    dense: DepthFrame,
    /// Frames published without a truth row for their seq (not scored).
    unscored: u64,
    /// The same errors by the eyes' speed ([`SPEED_BANDS_DEG_S`]).
    by_speed: [SpeedBand; 5],
    /// The frame's row nodes as quaternions (reused: nothing is allocated per frame).
    row_nodes: Vec<(UnitQuaternion<f64>, Vector3<f64>)>,
    /// The simulated head's truth, frame by frame as it renders (`poses` then holds the frame being scored).
    feed: Option<std::sync::Arc<crate::head::TruthFeed>>,
    /// The fovea's error and the main map's over the same rays (runs with a fovea; made at its first frame):
    /// all frames, then by fixation distance ([`FIXATION_BANDS_M`]).
    fovea: Option<Box<[[FoveaScore; 2]; 1 + FIXATION_BANDS_M.len()]>>,
}

/// Lower edges of the fixation-distance bands of `depth_error_fovea_by_distance` (m, the fovea's fixation
/// from the midpoint of the optical centres); nearer fixations are in no band.
pub const FIXATION_BANDS_M: [f64; 6] = [0.3, 0.5, 0.75, 1.0, 1.5, 2.0];

/// One map's error over the fovea's scored rays: sums and the point-error histogram (fixed size).
struct FoveaScore {
    err: DepthError,
    dist: SpeedBand,
}

impl FoveaScore {
    fn new() -> Self {
        FoveaScore { err: DepthError::default(), dist: SpeedBand::new() }
    }

    fn add(&mut self, est: &Vector3<f64>, origin: &Vector3<f64>, hit: &Vector3<f64>, r_true: f64) {
        let abs_rel = ((est - origin).norm() - r_true).abs() / r_true;
        let sq = (est - hit).norm_squared();
        self.err.abs_rel_sum += abs_rel;
        self.err.sq_sum += sq;
        self.err.points += 1;
        self.dist.abs_rel_sum += abs_rel;
        self.dist.points += 1;
        self.dist.add_distance(sq.sqrt() * 1e3);
    }

    fn json(&self) -> serde_json::Value {
        let mut v = self.err.json();
        let p50 = self.dist.point_mm_p50();
        v["point_mm_p50"] =
            if p50.is_finite() { serde_json::json!((p50 * 1e3).round() / 1e3) } else { serde_json::Value::Null };
        v["valid"] = v["valid_fraction"].clone();
        v
    }
}

impl TruthSink {
    /// The session's truth, or `None` for a recorded (non-synthetic) session.
    pub fn for_session(session: &Session, stride: usize) -> Result<Option<TruthSink>> {
        Self::for_meta(&session.dir, &session.meta, stride)
    }

    /// The truth of the session a replay plays (e.g. a [`abvs_runtime::Runtime`]'s), or `None` for a recorded
    /// one.
    pub fn for_replay(replay: &ReplaySource, stride: usize) -> Result<Option<TruthSink>> {
        Self::for_meta(replay.dir(), replay.meta(), stride)
    }

    fn for_meta(dir: &std::path::Path, meta: &SessionMeta, stride: usize) -> Result<Option<TruthSink>> {
        let Some(truth) = &meta.truth else { return Ok(None) };
        let model = |p: &std::path::Path, e: &dyn std::fmt::Display| RuntimeError::Model {
            path: p.to_path_buf(),
            msg: e.to_string(),
        };
        if truth.scene_generator != crate::synth::SCENE_GENERATOR {
            return Err(RuntimeError::Invalid(format!("unknown scene generator `{}`", truth.scene_generator)));
        }
        let scene = crate::synth::scene(truth.scene_seed)?;
        let sp = dir.join(&truth.stereo);
        let stereo = StereoCalibration::read_yaml(&sp).map_err(|e| model(&sp, &e))?;
        let up = dir.join(&truth.units[0]);
        let unit = UnitModel::load(&up).map_err(|e| model(&up, &e))?;
        let fk = unit.compile().map_err(|e| model(&up, &e))?;
        let pp = dir.join(&truth.poses);
        let frame_rows = read_angles(&pp, false)?;
        let node_rows = match &truth.row_poses {
            Some(r) => read_angles(&dir.join(r), true)?,
            None => Vec::new(),
        };
        let mut stream = fk.stream();
        let mut poses = Vec::with_capacity(frame_rows.len());
        let g = meta.gravity;
        let mut nodes = node_rows.iter().peekable();
        for (seq, _, v) in &frame_rows {
            let th = [v[0], v[1], v[2]];
            let p = fk.next(&mut stream, &th, g).map_err(|e| model(&up, &e))?;
            // the row nodes of this frame, with the motion history frozen at the frame (as the runtime does)
            let (cond, mut warm) = fk.peek(&stream, &th, g, None).map_err(|e| model(&up, &e))?;
            let mut rows = Vec::new();
            while let Some((_, _, n)) = nodes.next_if(|(s, _, _)| s == seq) {
                let (q, r) = fk.pose_unchecked(&[n[0], n[1], n[2]], &cond, Some(&warm)).map_err(|e| model(&up, &e))?;
                warm = r;
                rows.push(Pose::new(q.r, q.t * 1e-3));
            }
            poses.push((*seq, Pose::new(p.r, p.t * 1e-3), rows));
        }
        if let Some((seq, _, _)) = nodes.next() {
            return Err(RuntimeError::Invalid(format!("truth row poses: seq {seq} has no frame in {}", pp.display())));
        }
        let camera = abvs_runtime::tasks::rectify::camera_for_frames(&stereo.left, meta.width, meta.height)?;
        Ok(Some(TruthSink {
            scene,
            camera,
            poses,
            stride: stride.max(1),
            err: DepthError::default(),
            by_confidence: None,
            all_pixels: None,
            range: DepthConfig::default(),
            dense: DepthFrame::empty(),
            unscored: 0,
            by_speed: std::array::from_fn(|_| SpeedBand::new()),
            row_nodes: Vec::new(),
            feed: None,
            fovea: None,
        }))
    }

    /// The truth of the simulated head ([`crate::head::SimSource`]): its scene and lens, the poses from its
    /// feed by seq as it renders them.
    pub fn for_head(source: &crate::head::SimSource, stride: usize) -> Result<TruthSink> {
        let head = source.head();
        let camera =
            abvs_runtime::tasks::rectify::camera_for_frames(&head.stereo.left, head.spec.width, head.spec.height)?;
        Ok(TruthSink {
            scene: crate::synth::scene(head.spec.seed)?,
            camera,
            poses: Vec::with_capacity(1),
            stride: stride.max(1),
            err: DepthError::default(),
            by_confidence: None,
            all_pixels: None,
            range: DepthConfig::default(),
            dense: DepthFrame::empty(),
            unscored: 0,
            by_speed: std::array::from_fn(|_| SpeedBand::new()),
            row_nodes: Vec::new(),
            feed: Some(source.truth()),
            fovea: None,
        })
    }

    /// What was measured so far (sums over the frames scored).
    pub fn error(&self) -> DepthError {
        self.err
    }

    /// The index in `poses` of a frame of the session, by its seq.
    fn true_pose(&self, seq: u64) -> Option<usize> {
        self.poses.binary_search_by_key(&seq, |(s, _, _)| *s).ok()
    }
}

impl TruthSink {
    /// Scores point `j` of `depth` (the published map's, or the map before the mask): the raw pixel the
    /// pipeline took it from, where that pixel really looked (true pose at its row, ray into the true
    /// scene), and the point against that surface point. Returns (its rectified pixel, |r_est - r_true| /
    /// r_true, squared 3-D error in m^2), or `None` where the ray leaves the image or misses the scene.
    fn score_point(
        &self,
        out: &Published,
        depth: &DepthFrame,
        j: usize,
        frame_pose: &Pose,
        rows: Option<&RowRotations>,
    ) -> Option<(usize, f64, f64)> {
        let w = out.cam.width as usize;
        let cam_from_rect = out.rect.rect_from_left.transpose();
        let i = depth.pixel[j] as usize;
        let (u, v) = ((i % w) as f64, (i / w) as f64);
        let raw = source_pixel(&self.camera, out.cam, &cam_from_rect, rows, u, v)?;
        let dir = self.camera.unproject(&Vector2::new(raw.x, raw.y))?;
        let true_pose = pose_at_row(frame_pose, &self.row_nodes, raw.y, self.camera.height);
        let origin = Point3::from(true_pose.t);
        let hit = self.scene.cast(&origin, &(true_pose.r * dir))?;
        let p = depth.cloud[j];
        let est = Vector3::new(p.x as f64, p.y as f64, p.z as f64);
        let r_true = (hit.point - origin).norm();
        let r_est = (est - origin.coords).norm();
        Some((i, (r_est - r_true).abs() / r_true, (est - hit.point.coords).norm_squared()))
    }

    /// Scores the fovea and the main map along the same rays: every `stride`-th window pixel's ray, where the
    /// truth's surface is hit; the fovea's point at its depth, the main map's at the depth of its nearest
    /// pixel along the same ray (the main map upsampled to the fovea, nearest neighbour). Valid fractions are
    /// over the same pixels.
    fn score_fovea(&mut self, out: &Published, f: &FoveaFrame, frame_pose: &Pose, rows: Option<&RowRotations>) {
        let all =
            self.fovea.get_or_insert_with(|| Box::new(std::array::from_fn(|_| [FoveaScore::new(), FoveaScore::new()])));
        let band = FIXATION_BANDS_M.iter().rposition(|lo| f.fixation_distance_m >= *lo).map(|b| b + 1);
        let (first, rest) = all.split_at_mut(1);
        let scores = &mut first[0];
        let mut by_band = band.map(|b| &mut rest[b - 1]);
        let (fc, mc) = (&f.cam, out.cam);
        let cam_from_rect = out.rect.rect_from_left.transpose();
        // rectified -> left home camera
        let (r, t) = (out.pose.rel_left.r * cam_from_rect, out.pose.rel_left.t);
        let (fw, mw) = (fc.width as usize, mc.width as usize);
        for i in (0..f.depth.depth.len()).step_by(self.stride) {
            let (u, v) = ((i % fw) as f64, (i / fw) as f64);
            let Some(raw) = source_pixel(&self.camera, fc, &cam_from_rect, rows, u, v) else { continue };
            let Some(dir) = self.camera.unproject(&Vector2::new(raw.x, raw.y)) else { continue };
            let true_pose = pose_at_row(frame_pose, &self.row_nodes, raw.y, self.camera.height);
            let Some(hit) = self.scene.cast(&Point3::from(true_pose.t), &(true_pose.r * dir)) else { continue };
            let (origin, hit) = (true_pose.t, hit.point.coords);
            let r_true = (hit - origin).norm();
            let ray = Vector3::new((u - fc.cx) / fc.f, (v - fc.cy) / fc.f, 1.0);
            let at = |z: f64| r * (ray * z) + t;
            let z = f.depth.depth[i];
            let (um, vm) = ((ray.x * mc.f + mc.cx).round(), (ray.y * mc.f + mc.cy).round());
            let inside = um >= 0.0 && vm >= 0.0 && um < mc.width as f64 && vm < mc.height as f64;
            let zm = if inside { out.depth.depth[vm as usize * mw + um as usize] } else { f32::NAN };
            for s in std::iter::once(&mut *scores).chain(by_band.as_deref_mut()) {
                s[0].err.pixels += 1;
                s[1].err.pixels += 1;
                if z.is_finite() {
                    s[0].add(&at(z as f64), &origin, &hit, r_true);
                }
                if zm.is_finite() {
                    s[1].add(&at(zm as f64), &origin, &hit, r_true);
                }
            }
        }
    }
}

/// The true pose when raw row `y` exposed: between the frame's row nodes (node n at row n (H - 1) / N);
/// the frame's pose without nodes (global shutter).
fn pose_at_row(frame: &Pose, nodes: &[(UnitQuaternion<f64>, Vector3<f64>)], y: f64, rows: u32) -> Pose {
    if nodes.len() < 2 {
        return *frame;
    }
    let n = nodes.len() - 1;
    let g = (y / (rows.max(2) - 1) as f64 * n as f64).clamp(0.0, n as f64);
    let i = (g as usize).min(n - 1);
    let f = g - i as f64;
    let r = nodes[i].0.slerp(&nodes[i + 1].0, f).to_rotation_matrix().into_inner();
    Pose::new(r, nodes[i].1 * (1.0 - f) + nodes[i + 1].1 * f)
}

/// Rows of a truth angles file: `seq,l1..r3` or, `with_node`, `seq,node,l1..r3`: (seq, node, angles).
fn read_angles(path: &std::path::Path, with_node: bool) -> Result<Vec<(u64, usize, [f64; 6])>> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| RuntimeError::Model { path: path.to_path_buf(), msg: e.to_string() })?;
    let lead = if with_node { 2 } else { 1 };
    let mut out: Vec<(u64, usize, [f64; 6])> = Vec::new();
    for (i, line) in text.lines().enumerate().skip(1) {
        let at = |msg: String| RuntimeError::File { path: path.to_path_buf(), line: Some(i as u64 + 1), msg };
        let cols: Vec<&str> = line.split(',').map(str::trim).collect();
        if cols.len() != lead + 6 {
            let names = if with_node { "seq,node,l1,l2,l3,r1,r2,r3" } else { "seq,l1,l2,l3,r1,r2,r3" };
            return Err(at(format!("{} columns, expected {} ({names})", cols.len(), lead + 6)));
        }
        let seq: u64 = cols[0].parse().map_err(|e| at(format!("seq `{}`: {e}", cols[0])))?;
        let node: usize =
            if with_node { cols[1].parse().map_err(|e| at(format!("node `{}`: {e}", cols[1])))? } else { 0 };
        if let Some((prev, pn, _)) = out.last() {
            if (seq, node) <= (*prev, *pn) {
                return Err(at(format!("seq {seq} node {node} is not after the previous row's {prev} {pn}")));
            }
        }
        let mut v = [0.0; 6];
        for (k, x) in v.iter_mut().enumerate() {
            let c = cols[k + lead];
            *x = c.parse::<f64>().map_err(|e| at(format!("column {}: `{c}`: {e}", k + lead + 1)))?;
            if !x.is_finite() {
                return Err(at(format!("column {}: `{c}` is not finite", k + lead + 1)));
            }
        }
        out.push((seq, node, v));
    }
    Ok(out)
}

impl Sink for TruthSink {
    fn name(&self) -> &'static str {
        "truth"
    }

    fn wants_dense_disparity(&self) -> bool {
        true
    }

    fn consume(&mut self, out: &Published) -> Result<()> {
        if let Some(feed) = &self.feed {
            self.poses.clear();
            if let Some(t) = feed.get(out.session_seq) {
                self.poses.push((t.seq, t.left_rel, t.left_rows));
            }
        }
        let Some(k) = self.true_pose(out.session_seq) else {
            self.unscored += 1;
            return Ok(());
        };
        let frame_pose = self.poses[k].1;
        // the nodes' rotations as quaternions once per frame, not per scored point (from_matrix iterates)
        self.row_nodes.clear();
        self.row_nodes.extend(self.poses[k].2.iter().map(|p| (UnitQuaternion::from_matrix(&p.r), p.t)));
        let band = &mut self.by_speed[speed_band(out.motion.max_speed_deg_s())];
        if out.motion.gated {
            // invalid on purpose: counted by speed, not scored
            band.gated += 1;
            return Ok(());
        }
        band.frames += 1;
        let band_rot = &out.motion.band_rot[0];
        let rows = (!band_rot.is_empty()).then_some(RowRotations { nodes: band_rot, rows: self.camera.height });
        self.err.pixels += (out.depth.depth.len() / self.stride) as u64;
        for j in (0..out.depth.n_points).step_by(self.stride) {
            let Some((i, abs_rel, sq)) = self.score_point(out, out.depth, j, &frame_pose, rows.as_ref()) else {
                continue;
            };
            self.err.abs_rel_sum += abs_rel;
            self.err.sq_sum += sq;
            self.err.points += 1;
            let band = &mut self.by_speed[speed_band(out.motion.max_speed_deg_s())];
            band.abs_rel_sum += abs_rel;
            band.points += 1;
            band.add_distance(sq.sqrt() * 1e3);
            if let Some(conf) = out.confidence {
                let e = &mut self.by_confidence.get_or_insert_with(Default::default)
                    [if conf[i] > HIGH_CONFIDENCE { 0 } else { 1 }];
                e.abs_rel_sum += abs_rel;
                e.sq_sum += sq;
                e.points += 1;
            }
        }
        if let Some(dense) = out.dense_disparity {
            // the map before the validity mask, made into depth as the depth stage does, scored the same way
            let mut d = std::mem::replace(&mut self.dense, DepthFrame::empty());
            if d.depth.len() != dense.len() {
                d = DepthFrame::new(out.cam.width, out.cam.height);
            }
            let (rect, rel) = (out.rect, &out.pose.rel_left);
            abvs_runtime::tasks::depth::compute(
                &mut d,
                dense,
                |_| true,
                out.left_rect,
                out.cam,
                rect,
                rel,
                &self.range,
            );
            let all = self.all_pixels.get_or_insert_with(DepthError::default);
            all.pixels += (d.depth.len() / self.stride) as u64;
            for j in (0..d.n_points).step_by(self.stride) {
                if let Some((_, abs_rel, sq)) = self.score_point(out, &d, j, &frame_pose, rows.as_ref()) {
                    let all = self.all_pixels.get_or_insert_with(DepthError::default);
                    all.abs_rel_sum += abs_rel;
                    all.sq_sum += sq;
                    all.points += 1;
                }
            }
            self.dense = d;
        }
        if let Some(f) = out.fovea {
            self.score_fovea(out, f, &frame_pose, rows.as_ref());
        }
        Ok(())
    }

    fn finish(&mut self, stats: &mut RunStats) {
        // valid_fraction over the scored pixel stride
        stats.depth_error = Some(self.err);
        if let Some([hi, lo]) = &self.by_confidence {
            // (no valid fraction: the pixels are not split by confidence, only the points)
            let part = |e: &DepthError| {
                let mut v = e.json();
                if let Some(o) = v.as_object_mut() {
                    o.remove("valid_fraction");
                }
                v
            };
            stats.extra.insert(
                "depth_error_by_confidence".into(),
                serde_json::json!({ "threshold": HIGH_CONFIDENCE, "above": part(hi), "at_most": part(lo) }),
            );
        }
        if let Some(all) = &self.all_pixels {
            // the map before the validity mask: what the mask removed, scored (valid_fraction over every pixel)
            stats.extra.insert("depth_error_all_pixels".into(), all.json());
        }
        stats.extra.insert("truth_frames_unscored".into(), serde_json::json!(self.unscored));
        if let Some(f) = &self.fovea {
            stats.extra.insert("depth_error_fovea".into(), f[0][0].json());
            stats.extra.insert("depth_error_fovea_main".into(), f[0][1].json());
            let bands: Vec<serde_json::Value> = f[1..]
                .iter()
                .enumerate()
                .map(|(i, b)| {
                    let hi = FIXATION_BANDS_M.get(i + 1).map_or(serde_json::Value::Null, |h| serde_json::json!(h));
                    serde_json::json!({ "fixation_m": [FIXATION_BANDS_M[i], hi], "fovea": b[0].json(), "main": b[1].json() })
                })
                .collect();
            stats.extra.insert("depth_error_fovea_by_distance".into(), serde_json::Value::Array(bands));
        }
        let num =
            |x: f64| if x.is_finite() { serde_json::json!((x * 1e6).round() / 1e6) } else { serde_json::Value::Null };
        let bands: Vec<serde_json::Value> = self
            .by_speed
            .iter()
            .enumerate()
            .map(|(i, b)| {
                let hi = SPEED_BANDS_DEG_S.get(i + 1).map_or(serde_json::Value::Null, |h| serde_json::json!(h));
                serde_json::json!({
                    "deg_s": [SPEED_BANDS_DEG_S[i], hi],
                    "frames": b.frames,
                    "gated": b.gated,
                    "abs_rel": num(b.abs_rel()),
                    "point_mm_p50": num(b.point_mm_p50()),
                })
            })
            .collect();
        stats.extra.insert("depth_error_by_speed".into(), serde_json::Value::Array(bands));
    }
}
