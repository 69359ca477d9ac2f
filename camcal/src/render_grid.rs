//! Rendered AprilGrid images with ground truth: Kalibr AprilGrid textures (tag36h11 bits from
//! OpenCV's dictionary, 2-bit border, corner squares), the paper's setup of four boards about
//! 1.5 m in front of the eye, rendered through the lens by abvs-render at simulated camera poses.
//!
//! World frame = the home camera frame (OpenCV axes), millimetres in this module's API (the
//! renderer works in metres).
use crate::error::{CamcalError, Result};
use crate::target::AprilGridSpec;
use abvs_camera::Camera;
use abvs_eye::pose::exp_so3;
use abvs_eye::Pose;
use abvs_render::{Filter, RenderOptions, Rendered, Scene, Surface, Texture};
use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector2, Vector3};
use opencv::core::{Mat, Ptr};
use opencv::prelude::*;
use std::sync::Arc;

/// Texels per tag bit in the board textures.
const TEXELS_PER_BIT: usize = 10;
/// White margin around each board, in texels.
const MARGIN_TEXELS: usize = 30;

fn render_err(e: impl std::fmt::Display) -> CamcalError {
    CamcalError::Invalid(format!("render: {e}"))
}

/// Several AprilGrid boards posed in the world (home camera frame).
#[derive(Debug, Clone)]
pub struct GridScene {
    pub spec: AprilGridSpec,
    /// (board index, board -> world pose in mm; board frame as in [`crate::target`]).
    pub boards: Vec<(u32, Pose)>,
}

/// The 10x10 bit pattern (true = black) of tag36h11 `id` with its 2-bit black border, row 0 at
/// the top of the upright tag.
pub fn tag_bits(id: u32) -> Result<[[bool; 10]; 10]> {
    let dict: Ptr<opencv::aruco::Dictionary> =
        opencv::aruco::get_predefined_dictionary(opencv::aruco::PREDEFINED_DICTIONARY_NAME::DICT_APRILTAG_36h11)?;
    let mut img = Mat::default();
    opencv::aruco::draw_marker(&dict, id as i32, 10, &mut img, 2)?;
    let mut bits = [[false; 10]; 10];
    for (r, row) in bits.iter_mut().enumerate() {
        for (c, b) in row.iter_mut().enumerate() {
            // OpenCV's dictionary holds the codes rotated by 180 deg (see detect): turn them back
            *b = *img.at_2d::<u8>(9 - r as i32, 9 - c as i32)? < 128;
        }
    }
    Ok(bits)
}

/// How far the paper's scene puts its nearest boards from the home camera (mm).
pub const BOARDS_MM: f64 = 1500.0;

impl GridScene {
    /// The paper's setup: four boards (indices 0-3) in a 2x2 arrangement about 1.5 m in front
    /// of the home camera, each turned 12-18 deg toward the centre (a shallow bowl, which gives
    /// the scene depth).
    pub fn paper(spec: AprilGridSpec) -> GridScene {
        let [w, h] = spec.outer_size_mm();
        let gap = spec.tag_mm * spec.spacing;
        let mut boards = Vec::new();
        for (b, (sx, sy)) in [(-1.0, 1.0), (1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)].iter().enumerate() {
            // board centre in the world (y down: sy = 1 is the lower row)
            let centre = Vector3::new(sx * (0.5 * w + 40.0), sy * (0.5 * h + 40.0), BOARDS_MM + 60.0 * (b as f64));
            // facing the camera: board x = world x, board y (up) = -world y, board z = -world z,
            // then turned toward the centre about the world y and x axes
            let face = Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0));
            let tilt = exp_so3(&Vector3::new(sy * 0.22, -sx * 0.28, 0.03 * b as f64));
            let r = tilt * face;
            // origin = centre - r * (board-frame centre of the tag area)
            let c_board = Vector3::new(0.5 * w - gap, 0.5 * h - gap, 0.0);
            boards.push((b as u32, Pose::new(r, centre - r * c_board)));
        }
        GridScene { spec, boards }
    }

    /// The texture of board `board` (values 0 = black, 1 = white), `Nearest` filtered, and its
    /// size in texels.
    pub fn texture(&self, board: u32) -> Result<(Texture, usize, usize)> {
        let s = &self.spec;
        let gap_f = s.spacing * 10.0 * TEXELS_PER_BIT as f64;
        if (gap_f - gap_f.round()).abs() > 1e-6 {
            return Err(CamcalError::Invalid(format!("spacing {} must be a multiple of 0.01", s.spacing)));
        }
        let gap = gap_f.round() as usize;
        let tag = 10 * TEXELS_PER_BIT;
        let pitch = tag + gap;
        let (tw, th) = (s.cols * pitch + gap + 2 * MARGIN_TEXELS, s.rows * pitch + gap + 2 * MARGIN_TEXELS);
        let first = board * s.tags_per_board();
        let mut bits = Vec::with_capacity(s.cols * s.rows);
        for t in 0..s.tags_per_board() {
            bits.push(tag_bits(first + t)?);
        }
        let mut gray = vec![1.0f32; tw * th];
        for j in 0..th {
            for i in 0..tw {
                let (Some(px), Some(py)) = (i.checked_sub(MARGIN_TEXELS), j.checked_sub(MARGIN_TEXELS)) else {
                    continue;
                };
                if px >= s.cols * pitch + gap || py >= s.rows * pitch + gap {
                    continue;
                }
                let (cx, ox, cy, oy) = (px / pitch, px % pitch, py / pitch, py % pitch);
                let black = if ox < gap && oy < gap {
                    true
                } else if ox >= gap && oy >= gap && cx < s.cols && cy < s.rows {
                    let r = s.rows - 1 - cy; // tag row from the bottom
                    let b = &bits[r * s.cols + cx];
                    b[(oy - gap) / TEXELS_PER_BIT][(ox - gap) / TEXELS_PER_BIT]
                } else {
                    false
                };
                if black {
                    gray[j * tw + i] = 0.0;
                }
            }
        }
        let t = Texture::from_gray(tw, th, gray).map_err(render_err)?.with_filter(Filter::Nearest);
        Ok((t, tw, th))
    }

    /// Size of one texel in mm.
    fn texel_mm(&self) -> f64 {
        self.spec.tag_mm / (10 * TEXELS_PER_BIT) as f64
    }

    /// The renderer's scene (metres), background mid-grey.
    pub fn scene(&self) -> Result<Scene> {
        let mut scene = Scene::new(0.5);
        let tx = self.texel_mm();
        let gap = (self.spec.spacing * 10.0 * TEXELS_PER_BIT as f64).round() as usize;
        let pitch = 10 * TEXELS_PER_BIT + gap;
        for (b, pose) in &self.boards {
            let (tex, tw, th) = self.texture(*b)?;
            // texture-local (x right, y down, origin at the texture's top-left) from board frame
            let t_lb = Vector3::new(
                (MARGIN_TEXELS + gap) as f64 * tx,
                (MARGIN_TEXELS + self.spec.rows * pitch) as f64 * tx,
                0.0,
            );
            let local_from_board = Pose::new(Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0)), t_lb);
            let world_from_local = pose.compose(&local_from_board.inverse());
            let iso = to_iso_m(&world_from_local);
            let surf = Surface::rect(iso, tw as f64 * tx / 1000.0, th as f64 * tx / 1000.0, Arc::new(tex))
                .map_err(render_err)?;
            scene = scene.with(surf);
        }
        Ok(scene)
    }

    /// The true pixel positions of every corner visible in a camera at `cam` (camera -> world,
    /// mm): (corner id, pixel), for corners in front of the camera and inside the image.
    pub fn true_corners(&self, camera: &Camera, cam: &Pose) -> Vec<(u32, [f64; 2])> {
        let ci = cam.inverse();
        let mut out = Vec::new();
        for (b, pose) in &self.boards {
            for t in 0..self.spec.tags_per_board() {
                for k in 0..4 {
                    let x = self.spec.corner_mm(t, k);
                    let p = ci.compose(pose);
                    let pc = p.r * x + p.t;
                    if let Some(uv) = camera.project(&pc) {
                        if uv.x >= 0.0
                            && uv.y >= 0.0
                            && uv.x <= camera.width as f64 - 1.0
                            && uv.y <= camera.height as f64 - 1.0
                        {
                            let id = 4 * (b * self.spec.tags_per_board() + t) + k;
                            out.push((id, [uv.x, uv.y]));
                        }
                    }
                }
            }
        }
        let _ = Vector2::<f64>::zeros();
        out
    }

    /// Renders the scene from a camera at `cam` (camera -> world, mm).
    pub fn render(&self, scene: &Scene, camera: &Camera, cam: &Pose, opts: &RenderOptions) -> Result<Rendered> {
        abvs_render::render(scene, camera, &to_iso_m(cam), opts).map_err(render_err)
    }
}

/// A pose in mm as an isometry in metres.
pub fn to_iso_m(p: &Pose) -> Isometry3<f64> {
    let r = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(p.r));
    Isometry3::from_parts(Translation3::from(p.t / 1000.0), r)
}

/// A unit for rendered sessions: all kinematic effects of a drawn unit, no measurement noise
/// (the images are the measurement).
pub fn default_unit(seed: u64) -> abvs_eye::UnitModel {
    use abvs_eye::unit::Effect;
    let kin: Vec<Effect> = Effect::ALL.iter().copied().filter(|e| e.is_kinematic()).collect();
    let mut u = abvs_eye::sim::draw_unit(seed, &kin);
    u.set_enabled(Effect::MeasurementNoise, false);
    u
}

/// What to render in a simulated session.
#[derive(Debug, Clone)]
pub struct SimSessionSpec {
    pub sim: abvs_eye::sim::SimSpec,
    pub camera: Camera,
    pub grid: AprilGridSpec,
    /// Home images at the start of the session.
    pub home_images: usize,
    pub noise_sigma: f64,
    pub blur_sigma: f64,
    pub supersample: u32,
    pub home_counts: [i64; 3],
    /// Every n-th non-home image is written as an unreadable file (0: none).
    pub corrupt_every: usize,
}

impl Default for SimSessionSpec {
    fn default() -> Self {
        SimSessionSpec {
            sim: abvs_eye::sim::SimSpec { dropout: 0.0, ..Default::default() },
            camera: Camera::ov8856(),
            grid: AprilGridSpec::default(),
            home_images: 2,
            noise_sigma: 1.0,
            blur_sigma: 0.6,
            supersample: 4,
            home_counts: [1000, 26000, 47000],
            corrupt_every: 0,
        }
    }
}

/// Simulates a collection on `unit` (abvs-eye's simulator), renders the four-board scene at
/// every true camera pose and writes a session directory (session.toml, index.csv, images/,
/// camera.yaml = the true intrinsics, truth.csv = the true poses as a dataset file with the
/// session's seq). Returns the truth dataset (home rows first).
pub fn write_sim_session(
    dir: &std::path::Path,
    unit: &abvs_eye::UnitModel,
    spec: &SimSessionSpec,
    mut progress: impl FnMut(usize, usize),
) -> Result<abvs_eye::dataset::Dataset> {
    use crate::session::{counts_of, Row, Session, SessionMeta, FORMAT};
    use abvs_eye::dataset::{Dataset, Sample};
    std::fs::create_dir_all(dir.join("images"))?;
    let (sim, _) = abvs_eye::sim::simulate_dataset(unit, &spec.sim, |_, _| {})?;
    let nh = spec.home_images;
    let mut truth = Vec::new();
    for k in 0..nh {
        truth.push(Sample {
            seq: k as u64,
            t_s: 0.1 * k as f64,
            theta_deg: [0.0; 3],
            pose: [0.0; 6],
            cmd_deg: Some([0.0; 3]),
            gravity: Some(spec.sim.gravity),
            extra: vec![],
        });
    }
    for s in &sim.samples {
        let mut s = s.clone();
        s.seq += nh as u64;
        s.t_s += 0.1 * nh as f64;
        truth.push(s);
    }
    let grid = GridScene::paper(spec.grid);
    let scene = grid.scene()?;
    let rays = abvs_render::RayTable::new(&spec.camera).map_err(render_err)?;
    let mut rows = Vec::new();
    let n = truth.len();
    for (k, s) in truth.iter().enumerate() {
        progress(k, n);
        let image = format!("images/{:06}.png", s.seq);
        let path = dir.join(&image);
        let corrupt = spec.corrupt_every > 0 && k >= nh && (k - nh + 1) % spec.corrupt_every == 0;
        if corrupt {
            std::fs::write(&path, b"not a png")?;
        } else {
            let opts = RenderOptions {
                supersample: spec.supersample,
                blur_sigma: spec.blur_sigma,
                noise_sigma: spec.noise_sigma,
                seed: s.seq,
                ..Default::default()
            };
            let cam = Pose::from_p6(&s.pose);
            let img = abvs_render::render_with_rays(&scene, &rays, &to_iso_m(&cam), &opts).map_err(render_err)?;
            img.gray_image().save(&path).map_err(|e| CamcalError::File { path: path.clone(), msg: e.to_string() })?;
        }
        let counts = if k < nh { spec.home_counts } else { counts_of(&s.theta_deg, &spec.home_counts) };
        rows.push(Row { seq: s.seq, t_s: s.t_s, image, counts, cmd_deg: s.cmd_deg, gravity: s.gravity });
    }
    progress(n, n);
    let cam_path = dir.join("camera.yaml");
    spec.camera
        .write_yaml(&cam_path, &abvs_camera::CalibInfo::default())
        .map_err(|e| CamcalError::File { path: cam_path.clone(), msg: e.to_string() })?;
    let session = Session {
        dir: dir.to_path_buf(),
        meta: SessionMeta {
            format: FORMAT.into(),
            camera: "camera.yaml".into(),
            target: crate::target::Target::AprilGrid(spec.grid).to_string(),
            home_counts: spec.home_counts,
        },
        rows,
    };
    session.write()?;
    let ds = Dataset { samples: truth, extra_columns: vec![] };
    ds.write(&dir.join("truth.csv"))?;
    Ok(ds)
}

/// What to render in a simulated stereo calibration session at home.
#[derive(Debug, Clone)]
pub struct StereoSessionSpec {
    pub grid: AprilGridSpec,
    /// The head turns through `n x n` orientations (alpha, gamma in +-`half_range_deg`, with a
    /// little roll) and both cameras move with it, as on a rig turned in front of the boards.
    pub n: usize,
    pub half_range_deg: f64,
    /// Distances (mm) of the head from the boards' nearest row, each with all `n x n` orientations: at one
    /// distance, a camera a little further forward cannot be told from one with a slightly longer lens.
    pub distances_mm: Vec<f64>,
    pub noise_sigma: f64,
    pub blur_sigma: f64,
    pub supersample: u32,
    pub seed: u64,
}

impl Default for StereoSessionSpec {
    fn default() -> Self {
        StereoSessionSpec {
            grid: AprilGridSpec::default(),
            n: 3,
            half_range_deg: 20.0,
            distances_mm: vec![600.0, 1000.0, BOARDS_MM],
            noise_sigma: 1.0,
            blur_sigma: 0.6,
            supersample: 2,
            seed: 0,
        }
    }
}

/// Renders the four-board scene seen by both cameras of `truth` (intrinsics and T_lH^rH) from
/// the spec's head orientations and writes a stereo session (`stereo.toml`, `pairs.csv`,
/// `images/`) for `abvs calib stereo`, with the truth beside it as `truth.yaml`. Returns the
/// number of pairs.
pub fn write_stereo_sim_session(
    dir: &std::path::Path,
    truth: &abvs_camera::StereoCalibration,
    spec: &StereoSessionSpec,
    mut progress: impl FnMut(usize, usize),
) -> Result<usize> {
    use crate::session::{write_stereo_session, StereoMeta, STEREO_FORMAT};
    if spec.n < 2 {
        return Err(CamcalError::Invalid(format!("stereo session: {} orientations per axis (at least 2)", spec.n)));
    }
    // The lens model `abvs calib stereo` fits (one for both cameras).
    let model = |c: &Camera| match c.distortion {
        abvs_camera::Distortion::Fisheye(_) => "fisheye",
        abvs_camera::Distortion::Rational(_) => "rational",
        _ => "pinhole",
    };
    if model(&truth.left) != model(&truth.right) {
        return Err(CamcalError::Invalid("stereo session: both cameras must share one lens model".into()));
    }
    std::fs::create_dir_all(dir.join("images"))?;
    let grid = GridScene::paper(spec.grid);
    let scene = grid.scene()?;
    let rays = [
        abvs_render::RayTable::new(&truth.left).map_err(render_err)?,
        abvs_render::RayTable::new(&truth.right).map_err(render_err)?,
    ];
    // x_r = R x_l + T: the right camera in the left camera's frame.
    let rt = truth.rotation.transpose();
    let right_in_left = Pose::new(rt, -(rt * truth.translation_mm));
    let n = spec.n;
    if spec.distances_mm.is_empty() || spec.distances_mm.iter().any(|d| !(d.is_finite() && *d >= 200.0)) {
        return Err(CamcalError::Invalid(format!(
            "stereo session: distances {:?} mm (each 200 or more)",
            spec.distances_mm
        )));
    }
    let views = n * n * spec.distances_mm.len();
    let mut pairs = Vec::new();
    for k in 0..views {
        progress(k, views);
        let at = |i: usize| -spec.half_range_deg + 2.0 * spec.half_range_deg * i as f64 / (n - 1) as f64;
        let (alpha, gamma) = (at(k % (n * n) / n), at(k % n));
        // the head moved toward the boards (world z) from where the paper's scene puts them
        let ahead = BOARDS_MM - spec.distances_mm[k / (n * n)];
        let head = Pose::new(
            abvs_eye::Fick::from_deg([alpha, 0.15 * gamma, gamma]).to_matrix(),
            Vector3::new(0.0, 0.0, ahead),
        );
        let mut names = Vec::new();
        for (side, pose) in [(0, head), (1, head.compose(&right_in_left))] {
            let opts = RenderOptions {
                supersample: spec.supersample,
                blur_sigma: spec.blur_sigma,
                noise_sigma: spec.noise_sigma,
                seed: spec.seed.wrapping_mul(1_000_003).wrapping_add((2 * k + side) as u64),
                ..Default::default()
            };
            let img =
                abvs_render::render_with_rays(&scene, &rays[side], &to_iso_m(&pose), &opts).map_err(render_err)?;
            let name = format!("images/{}{:03}.png", ["left", "right"][side], k);
            let path = dir.join(&name);
            img.gray_image().save(&path).map_err(|e| CamcalError::File { path: path.clone(), msg: e.to_string() })?;
            names.push(name);
        }
        pairs.push((names[0].clone(), names[1].clone()));
    }
    progress(views, views);
    let meta = StereoMeta {
        format: STEREO_FORMAT.into(),
        target: crate::target::Target::AprilGrid(spec.grid).to_string(),
        model: model(&truth.left).into(),
    };
    write_stereo_session(dir, &meta, &pairs)?;
    let tp = dir.join("truth.yaml");
    truth.write_yaml(&tp).map_err(|e| CamcalError::File { path: tp.clone(), msg: e.to_string() })?;
    Ok(pairs.len())
}
