//! Camera poses relative to home from AprilGrid images: bundle adjustment over every corner of
//! every board in every image. Unknowns: the pose of each board in the home camera frame and the
//! pose of the camera of each non-home image relative to home (T_rel, conventions.md); the
//! camera of the home images is the identity (this fixes the gauge). Intrinsics are known.
//!
//! Levenberg-Marquardt with the camera poses eliminated by the Schur complement (the reduced
//! system has 6 x boards unknowns); Jacobians: numeric for the lens (dpixel / dpoint in the
//! camera frame, batched through OpenCV's projection), analytic for the rigid motions.
use crate::detect::Detection;
use crate::error::{CamcalError, Result};
use crate::target::Target;
use abvs_camera::Camera;
use abvs_eye::lm::{levenberg_marquardt, Damping, LmProblem};
use abvs_eye::pose::{exp_so3, skew};
use abvs_eye::Pose;
use nalgebra::{DMatrix, DVector, SMatrix, SVector, Vector2, Vector3};
use opencv::calib3d;
use opencv::core::{Mat, Point2d, Point3d, Vector};
use opencv::prelude::*;
use std::collections::BTreeMap;

type M6 = SMatrix<f64, 6, 6>;
type V6 = SVector<f64, 6>;
type M23 = SMatrix<f64, 2, 3>;
type M26 = SMatrix<f64, 2, 6>;

/// Why an image gave no pose.
#[derive(Debug, Clone, PartialEq)]
pub enum Failure {
    /// The image file could not be read (message).
    Unreadable(String),
    /// No corner of any board found.
    NoBoard,
    /// Fewer corners than required (count found).
    TooFewCorners(usize),
    /// The pose could not be initialised (no board with a known pose in view) or the solve
    /// left a large reprojection error (RMS px).
    NoPose(String),
}

impl std::fmt::Display for Failure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Failure::Unreadable(m) => write!(f, "unreadable image: {m}"),
            Failure::NoBoard => write!(f, "no board visible"),
            Failure::TooFewCorners(n) => write!(f, "too few corners ({n})"),
            Failure::NoPose(m) => write!(f, "no pose: {m}"),
        }
    }
}

/// Options of the solve.
#[derive(Debug, Clone, Copy)]
pub struct SolveOptions {
    /// Fewest corners (over all boards) for an image to be measured.
    pub min_corners: usize,
    /// Fewest corners of one board for it to count in the pose initialisation.
    pub min_board_corners: usize,
    /// Corners whose residual exceeds max(this, 5 x overall RMS) px after a first solve are dropped.
    pub outlier_px: f64,
    /// Images whose RMS reprojection error exceeds this after the solve are marked failed.
    pub max_image_rms_px: f64,
    pub max_iterations: usize,
}

impl Default for SolveOptions {
    fn default() -> Self {
        SolveOptions {
            min_corners: 20,
            min_board_corners: 8,
            outlier_px: 1.0,
            max_image_rms_px: 2.0,
            max_iterations: 50,
        }
    }
}

/// Result of the bundle adjustment.
#[derive(Debug, Clone)]
pub struct Solved {
    /// Per image: the camera pose relative to home (`Pose` maps current-camera points into the
    /// home camera frame; its translation is the optical centre in mm), or why there is none.
    pub poses: Vec<std::result::Result<Pose, Failure>>,
    /// Per image: RMS reprojection error (px) and corners used, when solved.
    pub image_rms: Vec<Option<(f64, usize)>>,
    /// Board poses in the home camera frame (board -> home), by board index.
    pub boards: BTreeMap<u32, Pose>,
    /// RMS reprojection error over all used corners, px.
    pub rms_px: f64,
    pub iterations: usize,
}

struct Obs {
    slot: usize,
    x: Vector3<f64>,
    uv: [f64; 2],
}

/// Pose of a board in the camera (board -> camera) from one image with IPPE on undistorted
/// normalised coordinates.
fn pnp(intr: &Camera, obs: &[(Vector3<f64>, [f64; 2])]) -> Result<Pose> {
    let mut n = Vec::with_capacity(obs.len());
    for o in obs {
        let ray = intr
            .unproject(&Vector2::new(o.1[0], o.1[1]))
            .ok_or_else(|| CamcalError::Calibration("pixel outside the lens model".into()))?;
        if ray.z <= 1e-6 {
            return Err(CamcalError::Calibration("ray beyond 90 deg".into()));
        }
        n.push([ray.x / ray.z, ray.y / ray.z]);
    }
    let obj: Vector<Point3d> = obs.iter().map(|o| Point3d::new(o.0.x, o.0.y, o.0.z)).collect();
    let img: Vector<Point2d> = n.iter().map(|p| Point2d::new(p[0], p[1])).collect();
    let k = Mat::from_slice_2d(&[[1.0f64, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])?;
    let (mut rv, mut tv) = (Mat::default(), Mat::default());
    let ok = calib3d::solve_pnp(&obj, &img, &k, &Mat::default(), &mut rv, &mut tv, false, calib3d::SOLVEPNP_IPPE)?;
    if !ok {
        return Err(CamcalError::Calibration("solvePnP failed".into()));
    }
    let g = |m: &Mat, i: i32| -> Result<f64> { Ok(*m.at_2d::<f64>(i, 0)?) };
    let w = Vector3::new(g(&rv, 0)?, g(&rv, 1)?, g(&rv, 2)?);
    let t = Vector3::new(g(&tv, 0)?, g(&tv, 1)?, g(&tv, 2)?);
    Ok(Pose::new(exp_so3(&w), t))
}

/// Projects camera-frame points (mm); NaN where the lens model has no image.
fn project(intr: &Camera, pts: &[[f64; 3]]) -> Result<Vec<[f64; 2]>> {
    Ok(pts
        .iter()
        .map(|p| match intr.project(&Vector3::new(p[0], p[1], p[2])) {
            Some(uv) if p[2] > 0.0 => [uv.x, uv.y],
            _ => [f64::NAN, f64::NAN],
        })
        .collect())
}

/// Projections and d(pixel)/d(camera-frame point) (central differences); `None` where the
/// point has no image.
fn project_with_jac(intr: &Camera, pc: &[Vector3<f64>]) -> Result<Vec<Option<([f64; 2], M23)>>> {
    Ok(pc
        .iter()
        .map(|p| {
            if p.z <= 0.0 {
                return None;
            }
            let uv = intr.project(p)?;
            let mut j = M23::zeros();
            let h = 1e-5 * p.norm().max(1.0);
            for a in 0..3 {
                let mut e = Vector3::zeros();
                e[a] = h;
                let (u1, u0) = (intr.project(&(p + e))?, intr.project(&(p - e))?);
                j[(0, a)] = (u1.x - u0.x) / (2.0 * h);
                j[(1, a)] = (u1.y - u0.y) / (2.0 * h);
            }
            Some(([uv.x, uv.y], j))
        })
        .collect())
}

fn apply_update(p: &Pose, d: &[f64]) -> Pose {
    let w = Vector3::new(d[0], d[1], d[2]);
    Pose::new(exp_so3(&w) * p.r, p.t + Vector3::new(d[3], d[4], d[5]))
}

/// Sum of squared residuals and per-image (sum, count).
fn cost(intr: &Camera, obs: &[Vec<Obs>], cams: &[Option<Pose>], boards: &[Pose]) -> Result<(f64, Vec<(f64, usize)>)> {
    let mut tot = 0.0;
    let mut per = vec![(0.0, 0usize); obs.len()];
    for (i, o) in obs.iter().enumerate() {
        let Some(c) = cams[i] else { continue };
        if o.is_empty() {
            continue;
        }
        let ci = c.inverse();
        let pts: Vec<[f64; 3]> = o
            .iter()
            .map(|ob| {
                let p = ci.r * (boards[ob.slot].r * ob.x + boards[ob.slot].t) + ci.t;
                [p.x, p.y, p.z]
            })
            .collect();
        let pr = project(intr, &pts)?;
        let s: f64 = pr
            .iter()
            .zip(o)
            .map(|(p, ob)| {
                let e = (p[0] - ob.uv[0]).powi(2) + (p[1] - ob.uv[1]).powi(2);
                if e.is_finite() {
                    e
                } else {
                    1e4 // a point without image counts as 100 px off
                }
            })
            .sum();
        per[i] = (s, o.len());
        tot += s;
    }
    Ok((tot, per))
}

/// Solves every image's camera pose relative to home. `dets[i]` is the detection of image i or
/// why it failed to give one; `home[i]` marks images taken at home.
pub fn solve(
    intr: &Camera,
    target: &Target,
    dets: &[std::result::Result<Detection, Failure>],
    home: &[bool],
    opts: &SolveOptions,
) -> Result<Solved> {
    let n = dets.len();
    let mut status: Vec<std::result::Result<(), Failure>> = vec![Ok(()); n];
    // board slots
    let mut slot_of: BTreeMap<u32, usize> = BTreeMap::new();
    let mut obs: Vec<Vec<Obs>> = Vec::with_capacity(n);
    for (i, d) in dets.iter().enumerate() {
        let mut o = Vec::new();
        match d {
            Err(f) => status[i] = Err(f.clone()),
            Ok(d) if d.corners.is_empty() => status[i] = Err(Failure::NoBoard),
            Ok(d) if d.corners.len() < opts.min_corners => status[i] = Err(Failure::TooFewCorners(d.corners.len())),
            Ok(d) => {
                for c in &d.corners {
                    let (b, x) = target.corner(c.id);
                    let next = slot_of.len();
                    let slot = *slot_of.entry(b).or_insert(next);
                    o.push(Obs { slot, x, uv: c.px });
                }
            }
        }
        obs.push(o);
    }
    let nb = slot_of.len();
    if !(0..n).any(|i| home[i] && status[i].is_ok()) {
        return Err(CamcalError::Calibration("no usable home image: the home pose is undefined".into()));
    }

    // --- initialisation: boards from home images, then cameras, then the remaining boards
    let mut boards: Vec<Option<Pose>> = vec![None; nb];
    let mut cams: Vec<Option<Pose>> = (0..n).map(|i| (home[i] && status[i].is_ok()).then(Pose::identity)).collect();
    let board_in_cam = |i: usize, s: usize| -> Option<Pose> {
        let v: Vec<(Vector3<f64>, [f64; 2])> = obs[i].iter().filter(|o| o.slot == s).map(|o| (o.x, o.uv)).collect();
        if v.len() < opts.min_board_corners {
            return None;
        }
        pnp(intr, &v).ok()
    };
    for _pass in 0..3 {
        for s in 0..nb {
            if boards[s].is_some() {
                continue;
            }
            for i in 0..n {
                if let (Some(c), Some(bc)) = (cams[i], board_in_cam(i, s)) {
                    boards[s] = Some(c.compose(&bc));
                    break;
                }
            }
        }
        for i in 0..n {
            if cams[i].is_some() || status[i].is_err() {
                continue;
            }
            // the board with the most corners among those with a known pose
            let mut best: Option<(usize, usize)> = None;
            for s in 0..nb {
                let cnt = obs[i].iter().filter(|o| o.slot == s).count();
                if boards[s].is_some() && cnt >= opts.min_board_corners && best.is_none_or(|b| cnt > b.1) {
                    best = Some((s, cnt));
                }
            }
            if let Some((s, _)) = best {
                if let Some(bc) = board_in_cam(i, s) {
                    cams[i] = Some(boards[s].expect("known").compose(&bc.inverse()));
                }
            }
        }
    }
    for i in 0..n {
        if status[i].is_ok() && cams[i].is_none() {
            status[i] = Err(Failure::NoPose("no board with a known pose in view".into()));
        }
    }
    // observations of boards that never got a pose are unusable
    for o in obs.iter_mut() {
        o.retain(|ob| boards[ob.slot].is_some());
    }
    for (i, c) in cams.iter_mut().enumerate() {
        if status[i].is_err() {
            *c = None;
        }
    }
    let mut bposes: Vec<Pose> = boards.iter().map(|b| b.unwrap_or_default()).collect();

    // --- LM, twice: after the first solve drop outlier corners
    let mut iterations = 0;
    for round in 0..2 {
        iterations += lm(intr, &obs, &mut cams, &mut bposes, home, opts.max_iterations)?;
        if round == 0 {
            let (tot, _) = cost(intr, &obs, &cams, &bposes)?;
            let cnt: usize = (0..n).filter(|&i| cams[i].is_some()).map(|i| obs[i].len()).sum();
            let rms = (tot / cnt.max(1) as f64).sqrt();
            let thr = opts.outlier_px.max(5.0 * rms);
            let mut dropped = 0;
            for i in 0..n {
                let Some(c) = cams[i] else { continue };
                let ci = c.inverse();
                let pts: Vec<[f64; 3]> = obs[i]
                    .iter()
                    .map(|ob| {
                        let p = ci.r * (bposes[ob.slot].r * ob.x + bposes[ob.slot].t) + ci.t;
                        [p.x, p.y, p.z]
                    })
                    .collect();
                if pts.is_empty() {
                    continue;
                }
                let pr = project(intr, &pts)?;
                let keep: Vec<bool> = pr
                    .iter()
                    .zip(&obs[i])
                    .map(|(p, ob)| ((p[0] - ob.uv[0]).powi(2) + (p[1] - ob.uv[1]).powi(2)).sqrt() <= thr)
                    .collect();
                let mut it = keep.iter();
                let before = obs[i].len();
                obs[i].retain(|_| *it.next().expect("same length"));
                dropped += before - obs[i].len();
            }
            if dropped == 0 {
                break;
            }
        }
    }
    let (tot, per) = cost(intr, &obs, &cams, &bposes)?;
    let cnt: usize = (0..n).filter(|&i| cams[i].is_some()).map(|i| obs[i].len()).sum();
    let mut image_rms = vec![None; n];
    let mut poses = Vec::with_capacity(n);
    for i in 0..n {
        match (&status[i], cams[i]) {
            (Err(f), _) => poses.push(Err(f.clone())),
            (Ok(()), None) => poses.push(Err(Failure::NoPose("not solved".into()))),
            (Ok(()), Some(c)) => {
                let rms = (per[i].0 / per[i].1.max(1) as f64).sqrt();
                image_rms[i] = Some((rms, per[i].1));
                if per[i].1 < opts.min_corners {
                    poses.push(Err(Failure::TooFewCorners(per[i].1)));
                } else if rms > opts.max_image_rms_px {
                    poses.push(Err(Failure::NoPose(format!("reprojection RMS {rms:.2} px"))));
                } else {
                    poses.push(Ok(c));
                }
            }
        }
    }
    let boards = slot_of.iter().filter(|(_, &s)| boards[s].is_some()).map(|(&b, &s)| (b, bposes[s])).collect();
    Ok(Solved { poses, image_rms, boards, rms_px: (tot / cnt.max(1) as f64).sqrt(), iterations })
}

/// Bundle adjustment for the shared LM loop: the normal equations with the Schur complement on
/// the board unknowns (each free camera's 6x6 block eliminated), one candidate step.
struct Adjust<'a> {
    intr: &'a Camera,
    obs: &'a [Vec<Obs>],
    cams: &'a mut [Option<Pose>],
    boards: &'a mut [Pose],
    home: &'a [bool],
    hbb: DMatrix<f64>,
    gb: DVector<f64>,
    cam_blocks: Vec<Option<(M6, V6, DMatrix<f64>)>>,
    cand: Option<(Vec<Option<Pose>>, Vec<Pose>)>,
}

impl LmProblem for Adjust<'_> {
    type Error = CamcalError;

    fn linearise(&mut self) -> Result<()> {
        let n = self.obs.len();
        let nbp = 6 * self.boards.len();
        let mut hbb = DMatrix::<f64>::zeros(nbp, nbp);
        let mut gb = DVector::<f64>::zeros(nbp);
        let mut cam_blocks: Vec<Option<(M6, V6, DMatrix<f64>)>> = Vec::with_capacity(n);
        for i in 0..n {
            let Some(c) = self.cams[i] else {
                cam_blocks.push(None);
                continue;
            };
            if self.obs[i].is_empty() {
                cam_blocks.push(None);
                continue;
            }
            let free = !self.home[i];
            let rt = c.r.transpose();
            let qs: Vec<Vector3<f64>> =
                self.obs[i].iter().map(|ob| self.boards[ob.slot].r * ob.x + self.boards[ob.slot].t).collect();
            let pc: Vec<Vector3<f64>> = qs.iter().map(|q| rt * (q - c.t)).collect();
            let pj = project_with_jac(self.intr, &pc)?;
            let mut hcc = M6::zeros();
            let mut gc = V6::zeros();
            let mut hcb = DMatrix::<f64>::zeros(6, nbp);
            for (k, ob) in self.obs[i].iter().enumerate() {
                let Some((pr, jpk)) = pj[k] else { continue };
                let r = Vector2::new(pr[0] - ob.uv[0], pr[1] - ob.uv[1]);
                let jq: M23 = jpk * rt; // d pixel / d q (home-frame point)
                let rbx = self.boards[ob.slot].r * ob.x;
                let mut jb = M26::zeros();
                jb.fixed_view_mut::<2, 3>(0, 0).copy_from(&(jq * -skew(&rbx)));
                jb.fixed_view_mut::<2, 3>(0, 3).copy_from(&jq);
                let o = 6 * ob.slot;
                let jbt_jb = jb.transpose() * jb;
                let mut blk = hbb.view_mut((o, o), (6, 6));
                blk += jbt_jb;
                let mut gv = gb.rows_mut(o, 6);
                gv += jb.transpose() * r;
                if free {
                    let mut jc = M26::zeros();
                    let d = qs[k] - c.t;
                    jc.fixed_view_mut::<2, 3>(0, 0).copy_from(&(jpk * (rt * skew(&d))));
                    jc.fixed_view_mut::<2, 3>(0, 3).copy_from(&(-(jpk * rt)));
                    hcc += jc.transpose() * jc;
                    gc += jc.transpose() * r;
                    let cross = jc.transpose() * jb;
                    let mut hv = hcb.view_mut((0, o), (6, 6));
                    hv += cross;
                }
            }
            cam_blocks.push(free.then_some((hcc, gc, hcb)));
        }
        self.hbb = hbb;
        self.gb = gb;
        self.cam_blocks = cam_blocks;
        Ok(())
    }

    fn try_step(&mut self, lambda: f64) -> Result<Option<f64>> {
        let n = self.obs.len();
        let nb = self.boards.len();
        let nbp = 6 * nb;
        let mut s = self.hbb.clone();
        for d in 0..nbp {
            s[(d, d)] += lambda * self.hbb[(d, d)] + 1e-9;
        }
        let mut rhs = -self.gb.clone();
        let mut inv_blocks: Vec<Option<M6>> = Vec::with_capacity(n);
        for b in &self.cam_blocks {
            let Some((hcc, gc, hcb)) = b else {
                inv_blocks.push(None);
                continue;
            };
            let mut h = *hcc;
            for d in 0..6 {
                h[(d, d)] += lambda * hcc[(d, d)] + 1e-9;
            }
            let Some(hi) = h.try_inverse() else {
                inv_blocks.push(None);
                continue;
            };
            let hbc = hcb.transpose(); // nbp x 6
            let hi_d = DMatrix::from_column_slice(6, 6, hi.as_slice());
            let t = &hbc * &hi_d; // nbp x 6
            s -= &t * hcb;
            rhs += &t * DVector::from_column_slice(gc.as_slice());
            inv_blocks.push(Some(hi));
        }
        let Some(db) = s.clone().lu().solve(&rhs) else {
            return Ok(None);
        };
        let nb_new: Vec<Pose> =
            (0..nb).map(|b| apply_update(&self.boards[b], &db.as_slice()[6 * b..6 * b + 6])).collect();
        let mut nc: Vec<Option<Pose>> = self.cams.to_vec();
        for i in 0..n {
            if let (Some((_, gc, hcb)), Some(hi)) = (&self.cam_blocks[i], &inv_blocks[i]) {
                let hcb_db = hcb * &db;
                let v = V6::from_column_slice(hcb_db.as_slice());
                let dc = -(hi * (gc + v));
                nc[i] = self.cams[i].map(|c| apply_update(&c, dc.as_slice()));
            }
        }
        let (newc, _) = cost(self.intr, self.obs, &nc, &nb_new)?;
        self.cand = Some((nc, nb_new));
        Ok(Some(newc))
    }

    fn accept(&mut self) {
        if let Some((nc, nb)) = self.cand.take() {
            self.boards.copy_from_slice(&nb);
            self.cams.copy_from_slice(&nc);
        }
    }
}

/// Levenberg-Marquardt with the Schur complement on the board unknowns. Returns iterations.
fn lm(
    intr: &Camera,
    obs: &[Vec<Obs>],
    cams: &mut [Option<Pose>],
    boards: &mut [Pose],
    home: &[bool],
    max_iter: usize,
) -> Result<usize> {
    // Gentler than Marquardt's 10 both ways on a worse step (x4 up, /3 down): tuned on the
    // rendered sessions' bundle adjustment; an unsolvable system still steps up by 10.
    let damping = Damping { increase: 4.0, decrease: 3.0, ..Damping::default() };
    let (cur, _) = cost(intr, obs, cams, boards)?;
    let mut p = Adjust {
        intr,
        obs,
        cams,
        boards,
        home,
        hbb: DMatrix::zeros(0, 0),
        gb: DVector::zeros(0),
        cam_blocks: vec![],
        cand: None,
    };
    Ok(levenberg_marquardt(&mut p, cur, max_iter, &damping)?.iterations)
}
