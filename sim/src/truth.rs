//! Depth accuracy against ground truth, for synthetic sessions.
//!
//! For a published point at rectified pixel (u, v), the pipeline's own chain says which raw pixel it came
//! from (rectifying rotation + lens); the truth says where that raw pixel really looked: the true camera pose
//! (true unit model at the true link angles) and a ray cast into the true scene. Errors compare the published
//! point with that true surface point: `abs_rel` = |r_est - r_true| / r_true (ranges from the true optical
//! centre) and `rmse_m` = RMS of the 3D distance. Points are scored on a fixed pixel stride (casting every
//! point would cost more than the pipeline). Frames are matched to their truth by `seq` (the first column of
//! the truth's poses file), never by position: a frame the replay could not read shifts nothing. When the run
//! computes a confidence, the points are also scored apart by it (above and at most [`HIGH_CONFIDENCE`]):
//! stats `depth_error_by_confidence`.
use abvs_camera::{Camera, StereoCalibration};
use abvs_eye::{Pose, UnitModel};
use abvs_render::Scene;
use nalgebra::{Point3, Vector2, Vector3};

use abvs_runtime::error::{Result, RuntimeError};
use abvs_runtime::pipeline::{Published, Sink};
use abvs_runtime::session::Session;
use abvs_runtime::sinks::stats::{DepthError, RunStats};

/// The confidence above which a point counts as confident in `depth_error_by_confidence`.
pub const HIGH_CONFIDENCE: f32 = 0.8;

pub struct TruthSink {
    scene: Scene,
    camera: Camera,
    /// True T_rel of the left eye per session frame (metres), by seq (increasing).
    poses: Vec<(u64, Pose)>,
    stride: usize,
    err: DepthError,
    /// The same over the points of confidence above [`HIGH_CONFIDENCE`], and the others (runs with one).
    by_confidence: Option<[DepthError; 2]>,
    /// Frames published without a truth row for their seq (not scored).
    unscored: u64,
}

impl TruthSink {
    /// The session's truth, or `None` for a recorded (non-synthetic) session.
    pub fn for_session(session: &Session, stride: usize) -> Result<Option<TruthSink>> {
        let Some(truth) = &session.meta.truth else { return Ok(None) };
        let model = |p: &std::path::Path, e: &dyn std::fmt::Display| RuntimeError::Model {
            path: p.to_path_buf(),
            msg: e.to_string(),
        };
        if truth.scene_generator != crate::synth::SCENE_GENERATOR {
            return Err(RuntimeError::Invalid(format!("unknown scene generator `{}`", truth.scene_generator)));
        }
        let scene = crate::synth::scene(truth.scene_seed)?;
        let sp = session.path(&truth.stereo);
        let stereo = StereoCalibration::read_yaml(&sp).map_err(|e| model(&sp, &e))?;
        let up = session.path(&truth.units[0]);
        let unit = UnitModel::load(&up).map_err(|e| model(&up, &e))?;
        let fk = unit.compile().map_err(|e| model(&up, &e))?;
        let pp = session.path(&truth.poses);
        let text = std::fs::read_to_string(&pp).map_err(|e| model(&pp, &e))?;
        let mut stream = fk.stream();
        let mut poses = Vec::new();
        for (i, line) in text.lines().enumerate().skip(1) {
            let at = |msg: String| RuntimeError::File { path: pp.clone(), line: Some(i as u64 + 1), msg };
            let cols: Vec<&str> = line.split(',').map(str::trim).collect();
            if cols.len() != 7 {
                return Err(at(format!("{} columns, expected 7 (seq,l1,l2,l3,r1,r2,r3)", cols.len())));
            }
            let seq: u64 = cols[0].parse().map_err(|e| at(format!("seq `{}`: {e}", cols[0])))?;
            if let Some((prev, _)) = poses.last() {
                if seq <= *prev {
                    return Err(at(format!("seq {seq} is not after the previous row's {prev}")));
                }
            }
            let mut v = [0.0; 6];
            for (k, x) in v.iter_mut().enumerate() {
                *x = cols[k + 1].parse::<f64>().map_err(|e| at(format!("column {}: `{}`: {e}", k + 2, cols[k + 1])))?;
            }
            let p = fk.next(&mut stream, &[v[0], v[1], v[2]], session.meta.gravity).map_err(|e| model(&up, &e))?;
            poses.push((seq, Pose::new(p.r, p.t * 1e-3)));
        }
        let camera = abvs_runtime::pipeline::camera_for_frames(&stereo.left, session.meta.width, session.meta.height)?;
        Ok(Some(TruthSink {
            scene,
            camera,
            poses,
            stride: stride.max(1),
            err: DepthError::default(),
            by_confidence: None,
            unscored: 0,
        }))
    }

    /// What was measured so far (sums over the frames scored).
    pub fn error(&self) -> DepthError {
        self.err
    }

    /// The true pose of the left eye for a frame of the session, by its seq.
    fn true_pose(&self, seq: u64) -> Option<Pose> {
        self.poses.binary_search_by_key(&seq, |(s, _)| *s).ok().map(|i| self.poses[i].1)
    }
}

impl Sink for TruthSink {
    fn name(&self) -> &'static str {
        "truth"
    }

    fn consume(&mut self, out: &Published) -> Result<()> {
        let Some(true_pose) = self.true_pose(out.session_seq) else {
            self.unscored += 1;
            return Ok(());
        };
        let w = out.cam.width as usize;
        let cam_from_rect = out.rect.rect_from_left.transpose();
        let origin = Point3::from(true_pose.t);
        self.err.pixels += (out.depth.depth.len() / self.stride) as u64;
        for j in (0..out.depth.n_points).step_by(self.stride) {
            let i = out.depth.pixel[j] as usize;
            let (u, v) = ((i % w) as f64, (i / w) as f64);
            let ray = cam_from_rect * Vector3::new((u - out.cam.cx) / out.cam.f, (v - out.cam.cy) / out.cam.f, 1.0);
            let Some(raw) = self.camera.project(&ray) else { continue };
            let Some(dir) = self.camera.unproject(&Vector2::new(raw.x, raw.y)) else { continue };
            let Some(hit) = self.scene.cast(&origin, &(true_pose.r * dir)) else { continue };
            let p = out.depth.points[j];
            let est = Vector3::new(p.x as f64, p.y as f64, p.z as f64);
            let r_true = (hit.point - origin).norm();
            let r_est = (est - origin.coords).norm();
            let (abs_rel, sq) = ((r_est - r_true).abs() / r_true, (est - hit.point.coords).norm_squared());
            self.err.abs_rel_sum += abs_rel;
            self.err.sq_sum += sq;
            self.err.points += 1;
            if let Some(conf) = out.confidence {
                let e = &mut self.by_confidence.get_or_insert_with(Default::default)
                    [if conf[i] > HIGH_CONFIDENCE { 0 } else { 1 }];
                e.abs_rel_sum += abs_rel;
                e.sq_sum += sq;
                e.points += 1;
            }
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
        stats.extra.insert("truth_frames_unscored".into(), serde_json::json!(self.unscored));
    }
}
