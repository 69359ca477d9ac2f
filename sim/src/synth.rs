//! Synthetic sessions with ground truth (`abvs sim session`): the simulator's units moving through saccades
//! and smooth pursuit in a textured 3D scene of known geometry, rendered through the wide-angle lens.
//!
//! - Scene "abvs-scene/1" ([`scene`]): rebuilt from its seed (exact geometry, no mesh files): a back wall,
//!   a floor, a slanted panel, boxes and spheres at 0.35-1.5 m, all with seeded multi-scale noise textures.
//!   World frame = the left eye's home camera frame.
//! - Two units drawn by abvs-eye's simulator (every effect of effects.md on), with a stereo rig at home
//!   (baseline ~65 mm, small rotation).
//! - Motion ([`crate::gaze_plan`]): both eyes fixate 3D targets in the scene (so they verge), jumping between
//!   them with saccades (minimum-jerk profile, peak speeds up to 1561 deg/s) and following targets that glide
//!   across and in depth (smooth pursuit, peak speed `pursuit_deg_s`); the whole motion is periodic, so a
//!   looped replay is seamless. The drive commands each eye's orientation through the nominal IK; the
//!   encoders read the link angles (1 kHz, quantised to counts, stamped late by the unit's
//!   encoder_time_offset, or by `time_offset_ms` for both eyes); the camera moves as the unit's true physics
//!   says.
//! - Calibration in the session: each eye's FK fitted by abvs-calib on a simulated calibration dataset of the
//!   same unit (what a user would have), the stereo calibration at home = the true one (issue 5 measures it).
//!
//! - Time (conventions.md "Time"): each row is rendered at its own instants. Row r of a frame starting at
//!   `t_start` exposes from `t_start + r * readout / (H - 1)` for `exposure`, integrated over enough time
//!   samples that the blur is right (at most half a pixel between samples); `readout = 0` is a global
//!   shutter, `exposure = 0` an instant. A frame's instant is its middle row's mid-exposure: `k / fps` for
//!   frame k. The truth (`truth/poses.csv`: true link angles per frame) is at that instant, so the truth
//!   depth is that of a global-shutter camera at mid-exposure, whatever the readout.
use std::path::Path;

use abvs_calib::methods::{fit, FitConfig, Method};
use abvs_calib::model::save_model;
use abvs_camera::{Camera, StereoCalibration};
use abvs_eye::encoder::COUNTS_PER_REV;
use abvs_eye::sim::{draw_unit, simulate_dataset, Commanded, SimSpec};
use abvs_eye::unit::{Effect, EncoderTimeOffset, UnitFk, UnitStream};
use abvs_eye::{Fick, Pose, SpmGeometry, UnitModel};
use abvs_render::{RayTable, RenderOptions, Scene, Surface, Texture, MAX_TIME_SAMPLES};
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use abvs_runtime_core::error::{Result, RuntimeError};
use abvs_runtime_core::session::{EncoderRecord, FrameRecord, Session, SessionMeta, Truth, SESSION_FORMAT};

use crate::gaze_plan::{GazePlan, DEFAULT_TARGET_DEPTH_M};

pub const SCENE_GENERATOR: &str = "abvs-scene/1";

/// Row nodes of `truth/row_poses.csv` per frame (node n at row n (H - 1) / N): 2 ms apart at a 32 ms
/// readout, where a pursuit's rotation is linear to well under 0.001 deg.
pub const TRUTH_ROW_NODES: usize = 16;

fn inv(e: impl std::fmt::Display) -> RuntimeError {
    RuntimeError::Invalid(e.to_string())
}

/// A seeded multi-scale value-noise texture (`n` x `n` texels over `size_m` metres): features at several
/// scales so stereo matching has something to lock on at every distance.
fn noise_texture(rng: &mut ChaCha8Rng, n: usize, size_m: [f64; 2]) -> Result<Texture> {
    let octaves: Vec<(usize, Vec<f32>, f32)> = [4usize, 12, 36, 108]
        .iter()
        .enumerate()
        .map(|(k, &g)| {
            let vals = (0..(g + 1) * (g + 1)).map(|_| rng.gen::<f32>()).collect();
            (g, vals, [0.3f32, 0.26, 0.26, 0.22][k])
        })
        .collect();
    let base = rng.gen_range(0.25f32..0.6);
    let contrast = rng.gen_range(0.6f32..1.0);
    Texture::from_texel_fn(n, n, move |x, y| {
        let mut v = 0.0;
        for (g, vals, amp) in &octaves {
            let fx = x as f32 / n as f32 * *g as f32;
            let fy = y as f32 / n as f32 * *g as f32;
            let (ix, iy) = ((fx as usize).min(g - 1), (fy as usize).min(g - 1));
            let (tx, ty) = (fx - ix as f32, fy - iy as f32);
            let (sx, sy) = (tx * tx * (3.0 - 2.0 * tx), ty * ty * (3.0 - 2.0 * ty));
            let at = |i: usize, j: usize| vals[j * (g + 1) + i];
            let a = at(ix, iy) * (1.0 - sx) + at(ix + 1, iy) * sx;
            let b = at(ix, iy + 1) * (1.0 - sx) + at(ix + 1, iy + 1) * sx;
            v += amp * (a * (1.0 - sy) + b * sy);
        }
        (base + contrast * (v - 0.5)).clamp(0.02, 0.98)
    })
    .and_then(|t| t.with_metric_size(size_m[0], size_m[1]))
    .map_err(inv)
}

/// The scene of generator "abvs-scene/1" for a seed.
pub fn scene(seed: u64) -> Result<Scene> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5ce4e);
    let mut s = Scene::new(0.5);
    let iso = |t: [f64; 3], r: Rotation3<f64>| {
        Isometry3::from_parts(Translation3::new(t[0], t[1], t[2]), UnitQuaternion::from_rotation_matrix(&r))
    };
    // back wall at 1.5 m, floor 0.45 m below the eyes
    s = s.with(
        Surface::rect_centred(
            iso([0.0, 0.0, 1.5], Rotation3::identity()),
            4.0,
            3.0,
            noise_texture(&mut rng, 1024, [4.0, 3.0])?,
        )
        .map_err(inv)?,
    );
    s = s.with(
        Surface::rect_centred(
            iso([0.0, 0.45, 0.85], Rotation3::from_axis_angle(&Vector3::x_axis(), std::f64::consts::FRAC_PI_2)),
            4.0,
            1.4,
            noise_texture(&mut rng, 1024, [4.0, 1.4])?,
        )
        .map_err(inv)?,
    );
    // a slanted panel
    let yaw = rng.gen_range(-0.9..0.9);
    s = s.with(
        Surface::rect_centred(
            iso(
                [rng.gen_range(-0.3..0.3), rng.gen_range(-0.15..0.05), rng.gen_range(0.8..1.1)],
                Rotation3::from_euler_angles(0.2, yaw, 0.0),
            ),
            0.5,
            0.4,
            noise_texture(&mut rng, 512, [0.5, 0.4])?,
        )
        .map_err(inv)?,
    );
    for _ in 0..4 {
        let h = Vector3::new(rng.gen_range(0.04..0.12), rng.gen_range(0.04..0.12), rng.gen_range(0.04..0.12));
        let c = [rng.gen_range(-0.4..0.4), rng.gen_range(-0.2..0.3), rng.gen_range(0.4..1.2)];
        let r =
            Rotation3::from_euler_angles(rng.gen_range(-0.3..0.3), rng.gen_range(-1.0..1.0), rng.gen_range(-0.2..0.2));
        s = s.with(Surface::cuboid(iso(c, r), h, noise_texture(&mut rng, 256, [0.3, 0.3])?).map_err(inv)?);
    }
    for _ in 0..2 {
        let c = Point3::new(rng.gen_range(-0.35..0.35), rng.gen_range(-0.15..0.25), rng.gen_range(0.5..1.2));
        s = s.with(
            Surface::sphere(c, rng.gen_range(0.05..0.12), noise_texture(&mut rng, 512, [1.0, 1.0])?).map_err(inv)?,
        );
    }
    Ok(s)
}

/// Both units of a seed (every effect of effects.md on): what `abvs sim session --seed` and the simulated head
/// (`crate::head`) draw.
pub fn units_for(seed: u64) -> [UnitModel; 2] {
    [draw_unit(seed * 2 + 11, &Effect::ALL), draw_unit(seed * 2 + 12, &Effect::ALL)]
}

/// The stereo rig at home drawn from `rng` (T_lH^rH, metres) and its calibration at `width` x `height` (the true
/// one: issue 5 measures it).
pub fn rig(rng: &mut ChaCha8Rng, width: u32, height: u32) -> (Pose, StereoCalibration) {
    let r_home = Rotation3::from_euler_angles(
        rng.gen_range(-0.008..0.008),
        rng.gen_range(-0.008..0.008),
        rng.gen_range(-0.005..0.005),
    );
    let t_home = Vector3::new(
        -0.065 + rng.gen_range(-0.001..0.001),
        rng.gen_range(-0.0005..0.0005),
        rng.gen_range(-0.0005..0.0005),
    );
    let camera = Camera::ov8856().scaled(width, height);
    let stereo = StereoCalibration {
        left: camera,
        right: camera,
        rotation: r_home.into_inner(),
        translation_mm: t_home * 1000.0,
        rms_px: None,
    };
    (Pose::new(r_home.into_inner(), t_home), stereo)
}

/// One eye's FK calibrated as a user would: a simulated calibration dataset of `unit` (grid step `step_deg`,
/// measurement noise from `data_seed`), fitted with `method`, saved as an FK model directory `dir`. The
/// unit's encoder latency is copied: it is not in a static dataset (the discrepancy workflow measures it, issue 4).
pub fn calibrate_unit(
    unit: &UnitModel,
    method: Method,
    step_deg: f64,
    data_seed: u64,
    fit_seed: u64,
    dir: &Path,
) -> Result<()> {
    let sim = SimSpec { commanded: Commanded::Step(step_deg), seed: data_seed, ..SimSpec::default() };
    let (data, _) = simulate_dataset(unit, &sim, |_, _| {}).map_err(inv)?;
    let cfg = FitConfig { seed: fit_seed, ..FitConfig::default() };
    let mut parts = fit(method, &data, None, &cfg, &mut |_, _, _, _, _| {}).map_err(inv)?;
    if let Some(u) = parts.unit.as_mut() {
        u.effects.encoder_time_offset = unit.effects.encoder_time_offset.clone();
    }
    save_model(dir, &parts).map_err(|e| RuntimeError::File { path: dir.to_path_buf(), line: None, msg: e.to_string() })
}

/// What `abvs sim session` makes.
#[derive(Debug, Clone)]
pub struct SessionSpec {
    pub seed: u64,
    pub frames: usize,
    pub fps: f64,
    /// Exposure of every row (ms); 0 = an instant (no motion blur).
    pub exposure_ms: f64,
    /// Rolling-shutter readout, first row's start of exposure to the last row's (ms); 0 = global shutter.
    pub readout_ms: f64,
    /// Peak angular speed of the smooth pursuits (deg/s); 0 = fixations and saccades only.
    pub pursuit_deg_s: f64,
    /// Depth range of the gaze plan's targets (z, m, near and far; [`DEFAULT_TARGET_DEPTH_M`] by default).
    pub fixation_m: [f64; 2],
    /// encoder_time_offset of both eyes (ms: the encoder stream is stamped this much late); `None` keeps
    /// each drawn unit's own.
    pub time_offset_ms: Option<f64>,
    pub width: u32,
    pub height: u32,
    pub encoder_hz: f64,
    /// FK calibration method fitted for each eye.
    pub fk_method: Method,
    /// Grid step (deg) of the simulated calibration dataset.
    pub calib_step_deg: f64,
    pub supersample: u32,
    pub noise_sigma: f64,
    pub threads: usize,
}

impl Default for SessionSpec {
    fn default() -> Self {
        SessionSpec {
            seed: 1,
            frames: 50,
            fps: 25.0,
            exposure_ms: 4.0,
            readout_ms: 0.0,
            pursuit_deg_s: 30.0,
            fixation_m: DEFAULT_TARGET_DEPTH_M,
            time_offset_ms: None,
            width: 800,
            height: 600,
            encoder_hz: 1000.0,
            fk_method: Method::Hybrid,
            calib_step_deg: 6.0,
            supersample: 2,
            noise_sigma: 1.5,
            threads: 2,
        }
    }
}

impl SessionSpec {
    /// Refuses a spec the session format or the encoder stream cannot hold, naming the field.
    #[allow(clippy::neg_cmp_op_on_partial_ord)] // `!(lo <= x && x <= hi)` refuses NaN too
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(RuntimeError::Invalid(m));
        if !(self.fps > 0.0 && self.fps <= 200.0) {
            return bad(format!("fps {} must be in (0, 200]", self.fps));
        }
        let frame_ms = 1e3 / self.fps;
        if !(0.0..=frame_ms).contains(&self.exposure_ms) {
            return bad(format!("exposure {} ms must be in [0, {frame_ms}] (one frame period)", self.exposure_ms));
        }
        // The encoder stream spans one loop period; every row's mid-exposure (and 1 ms either side, for the
        // runtime's speed) must fall inside it: the rows of one frame may span at most a frame period - 4 ms.
        if !(0.0..=frame_ms - 4.0).contains(&self.readout_ms) {
            return bad(format!(
                "readout {} ms must be in [0, {}] (frame period - 4 ms)",
                self.readout_ms,
                frame_ms - 4.0
            ));
        }
        if !(0.0..=500.0).contains(&self.pursuit_deg_s) {
            return bad(format!("pursuit peak {} deg/s must be in [0, 500]", self.pursuit_deg_s));
        }
        let [near, far] = self.fixation_m;
        if !(0.2 <= near && near < far && far <= 5.0) {
            return bad(format!("fixation depths {near}..{far} m must satisfy 0.2 <= near < far <= 5"));
        }
        if let Some(t) = self.time_offset_ms {
            if !(0.0..=10.0).contains(&t) {
                return bad(format!("time offset {t} ms must be in [0, 10] (effects.md: 0.1 - 5 ms)"));
            }
        }
        if self.frames == 0 || self.width < 16 || self.height < 16 {
            return bad(format!(
                "{} frames of {}x{} px: need at least one frame of 16x16",
                self.frames, self.width, self.height
            ));
        }
        Ok(())
    }
}

/// One eye's true pose (world from camera, metres) over one frame's exposure window, sampled densely and
/// interpolated (slerp): the unit's FK runs per node, not per row and time sample.
struct PoseTrack {
    t0: f64,
    dt: f64,
    nodes: Vec<Isometry3<f64>>,
}

impl PoseTrack {
    /// Node spacing (s): at the saccades' ~2e5 deg/s^2 a slerp between nodes errs by a h^2 / 8 ~ 0.002 deg.
    const STEP_S: f64 = 0.25e-3;

    fn pose_at(&self, t: f64) -> Isometry3<f64> {
        if self.nodes.len() == 1 {
            return self.nodes[0];
        }
        let g = ((t - self.t0) / self.dt).clamp(0.0, (self.nodes.len() - 1) as f64);
        let i = (g as usize).min(self.nodes.len() - 2);
        self.nodes[i].lerp_slerp(&self.nodes[i + 1], g - i as f64)
    }
}

/// When one frame exposes (s, on the session's clock): see the module doc's "Time".
pub(crate) struct FrameTiming {
    pub t_start: f64,
    pub t_frame: f64,
    pub readout: f64,
    pub exposure: f64,
    pub height: u32,
}

/// What both eyes of a head render through: the scene, the lens's rays and the rig at home.
pub(crate) struct EyeView<'a> {
    pub scene: &'a Scene,
    pub rays: &'a RayTable,
    pub camera: &'a Camera,
    /// T_world^rH (world = left home camera frame, metres).
    pub world_from_rhome: &'a Pose,
}

/// The render settings of eye `eye` (the right camera's gain and offset differ a little, as real ones do).
pub(crate) fn eye_render_options(
    eye: usize,
    supersample: u32,
    noise_sigma: f64,
    seed: u64,
    threads: usize,
) -> RenderOptions {
    RenderOptions {
        supersample,
        blur_sigma: 0.5,
        vignetting: 0.35,
        gain: if eye == 0 { 1.0 } else { 0.93 },
        offset: if eye == 0 { 0.0 } else { 4.0 },
        noise_sigma,
        seed,
        threads,
        ..RenderOptions::default()
    }
}

impl EyeView<'_> {
    /// One eye's frame: the true unit's pose from its true link angles at every row's time samples
    /// (`angles_at(t)`, deg), with rolling shutter and motion blur. The frame's own link angles `th_frame`
    /// advance the unit's motion history (backlash); over the exposure window it is frozen at the frame, as the
    /// truth and the runtime hold it.
    #[allow(clippy::too_many_arguments)]
    pub fn render(
        &self,
        eye: usize,
        fk: &UnitFk,
        stream: &mut UnitStream,
        th_frame: &[f64; 3],
        angles_at: &dyn Fn(f64) -> Result<[f64; 3]>,
        ft: &FrameTiming,
        opts: &RenderOptions,
    ) -> Result<abvs_render::Rendered> {
        let (camera, world_from_rhome) = (self.camera, self.world_from_rhome);
        let (t_start, t_frame, readout, exposure) = (ft.t_start, ft.t_frame, ft.readout, ft.exposure);
        let h1 = (ft.height - 1).max(1) as f64;
        let world_from = |rel: Pose| {
            let rel_m = Pose::new(rel.r, rel.t * 1e-3);
            let world = if eye == 0 { rel_m } else { world_from_rhome.compose(&rel_m) };
            Isometry3::from_parts(
                Translation3::from(world.t),
                UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(world.r)),
            )
        };
        let g = [0.0, 1.0, 0.0];
        fk.next(stream, th_frame, g).map_err(inv)?;
        let (cond, mut warm) = fk.peek(stream, th_frame, g, None).map_err(inv)?;
        let span = readout + exposure;
        let n_nodes = if span > 0.0 { (span / PoseTrack::STEP_S).ceil() as usize + 1 } else { 1 };
        let dt = if n_nodes > 1 { span / (n_nodes - 1) as f64 } else { 0.0 };
        let mut nodes = Vec::with_capacity(n_nodes);
        for i in 0..n_nodes {
            let t = if n_nodes > 1 { t_start + i as f64 * dt } else { t_frame };
            let (rel, r) = fk.pose_unchecked(&angles_at(t)?, &cond, Some(&warm)).map_err(inv)?;
            warm = r;
            nodes.push(world_from(rel));
        }
        let track = PoseTrack { t0: t_start, dt, nodes };
        // time samples: the largest blur over the rows, at most half a pixel between samples
        let blur_px = [0.0, 0.5, 1.0]
            .iter()
            .map(|f| {
                let t = t_start + f * readout;
                let (a, b) = (track.pose_at(t), track.pose_at(t + exposure));
                a.rotation.angle_to(&b.rotation) * camera.fx.max(camera.fy)
            })
            .fold(0.0, f64::max);
        let time_samples = if exposure > 0.0 { ((2.0 * blur_px).ceil() as usize + 1).min(MAX_TIME_SAMPLES) } else { 1 };
        let ks = time_samples as f64;
        let pose_at =
            |y: usize, s: usize| track.pose_at(t_start + y as f64 * readout / h1 + (s as f64 + 0.5) / ks * exposure);
        abvs_render::render_moving(self.scene, self.rays, &pose_at, time_samples, opts).map_err(inv)
    }
}

/// Writes an 8-bit gray PNG. Rendered frames carry sensor noise, which LZ77 matching cannot exploit: the
/// fast (Huffman-oriented) deflate with adaptive filters stores them ~10 % smaller than zlib at its best
/// (optipng's choice too: filter 5, Huffman-only), and sessions are shipped (the fixture) and replayed.
fn save_png(img: &image::GrayImage, path: &Path) -> std::result::Result<(), image::ImageError> {
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    use image::ImageEncoder;
    let file = std::io::BufWriter::new(std::fs::File::create(path)?);
    PngEncoder::new_with_quality(file, CompressionType::Fast, FilterType::Adaptive).write_image(
        img.as_raw(),
        img.width(),
        img.height(),
        image::ExtendedColorType::L8,
    )
}

/// Fick angles (deg) that point a camera at home pose `home_from_world` at `target` (beta = 0).
fn look_at(home_from_world: &Pose, target: &Vector3<f64>) -> [f64; 3] {
    let d = (home_from_world.r * target + home_from_world.t).normalize();
    [(-d.y).asin().to_degrees(), 0.0, d.x.atan2(d.z).to_degrees()]
}

/// Writes a synthetic session into `dir`. `progress(stage, done, total)`.
pub fn generate(spec: &SessionSpec, dir: &Path, progress: &mut dyn FnMut(&str, usize, usize)) -> Result<()> {
    spec.validate()?;
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    let fdir = dir.join("frames");
    for d in [dir.to_path_buf(), fdir.clone(), dir.join("calib"), dir.join("truth")] {
        std::fs::create_dir_all(&d).map_err(|e| RuntimeError::File {
            path: d.clone(),
            line: None,
            msg: e.to_string(),
        })?;
    }
    let io = |p: &Path, e: &dyn std::fmt::Display| RuntimeError::File {
        path: p.to_path_buf(),
        line: None,
        msg: e.to_string(),
    };
    let mut units = units_for(spec.seed);
    if let Some(t) = spec.time_offset_ms {
        for u in &mut units {
            u.effects.encoder_time_offset = EncoderTimeOffset { enabled: true, latency_ms: t };
        }
    }
    let (home_l_to_r, stereo) = rig(&mut rng, spec.width, spec.height);
    let world_from_rhome = home_l_to_r.inverse();
    let camera = stereo.left;
    let cam_err = |e: abvs_camera::CameraError| inv(e);
    stereo.write_yaml(dir.join("calib/stereo.yaml")).map_err(cam_err)?;
    stereo.write_yaml(dir.join("truth/stereo.yaml")).map_err(cam_err)?;
    for (i, u) in units.iter().enumerate() {
        let p = dir.join(format!("truth/unit{i}.toml"));
        u.save(&p).map_err(|e| io(&p, &e))?;
    }

    // ---- motion and encoders
    let period = spec.frames as f64 / spec.fps;
    let gaze = GazePlan::new(&mut rng, period, spec.pursuit_deg_s, spec.fixation_m);
    let nominal = SpmGeometry::nominal();
    let homes = [Pose::identity(), home_l_to_r];
    let readings = |eye: usize, t: f64| -> Result<[f64; 3]> {
        let f = look_at(&homes[eye], &gaze.at(t));
        let th = nominal.ik_checked(&Fick::from_deg(f).to_matrix()).map_err(inv)?;
        Ok(th.map(f64::to_degrees))
    };
    let t0_ns: i64 = 1_000_000_000;
    let ns = |t: f64| t0_ns + (t * 1e9).round() as i64;
    let mut encoders = Vec::new();
    let n_enc = (period * spec.encoder_hz).round() as usize;
    for k in 0..n_enc {
        // one period of samples starting half a frame before the first frame's instant: periodic, so looping
        // is seamless, and every row's mid-exposure of every frame lies inside (SessionSpec::validate)
        let t = k as f64 / spec.encoder_hz - 0.5 / spec.fps;
        for (eye, unit) in units.iter().enumerate() {
            let th = readings(eye, t)?;
            let c = th.map(|d| (d * COUNTS_PER_REV as f64 / 360.0).round() as i64);
            // the board stamps a sample `latency` after the links were there
            let stamp = unit.encoder_time_for_camera(0.0).abs();
            encoders.push(EncoderRecord {
                t_ns: ns(t + stamp),
                eye: eye as u8,
                count1: c[0],
                count2: c[1],
                count3: c[2],
            });
        }
    }
    encoders.sort_by_key(|e| (e.t_ns, e.eye));

    // ---- frames
    let scene = scene(spec.seed)?;
    let rays = RayTable::new(&camera).map_err(inv)?;
    let fks = [units[0].compile().map_err(inv)?, units[1].compile().map_err(inv)?];
    let mut streams = [fks[0].stream(), fks[1].stream()];
    let (readout, exposure) = (spec.readout_ms * 1e-3, spec.exposure_ms * 1e-3);
    let exposure_ns = (spec.exposure_ms * 1e6).round() as i64;
    let mut frames = Vec::new();
    let mut truth_rows = String::from("seq,l1,l2,l3,r1,r2,r3\n");
    let mut truth_row_nodes = String::from("seq,node,l1,l2,l3,r1,r2,r3\n");
    for k in 0..spec.frames {
        progress("render", k, spec.frames);
        // the frame's instant: its middle row's mid-exposure; row 0 starts readout / 2 + exposure / 2 earlier
        let t_frame = k as f64 / spec.fps;
        let t_start = t_frame - readout / 2.0 - exposure / 2.0;
        let th = [readings(0, t_frame)?, readings(1, t_frame)?];
        truth_rows += &format!(
            "{k},{:.9},{:.9},{:.9},{:.9},{:.9},{:.9}\n",
            th[0][0], th[0][1], th[0][2], th[1][0], th[1][1], th[1][2]
        );
        for n in 0..=TRUTH_ROW_NODES {
            // row n (H - 1) / N's mid-exposure
            let t = t_frame - readout / 2.0 + n as f64 * readout / TRUTH_ROW_NODES as f64;
            let (l, r) = (readings(0, t)?, readings(1, t)?);
            truth_row_nodes +=
                &format!("{k},{n},{:.9},{:.9},{:.9},{:.9},{:.9},{:.9}\n", l[0], l[1], l[2], r[0], r[1], r[2]);
        }
        let mut names = [String::new(), String::new()];
        for eye in 0..2 {
            let opts = eye_render_options(
                eye,
                spec.supersample,
                spec.noise_sigma,
                spec.seed * 1_000_003 + (k * 2 + eye) as u64,
                spec.threads,
            );
            let angles_at = |t: f64| readings(eye, t);
            let view = EyeView { scene: &scene, rays: &rays, camera: &camera, world_from_rhome: &world_from_rhome };
            let timing = FrameTiming { t_start, t_frame, readout, exposure, height: spec.height };
            let img = view.render(eye, &fks[eye], &mut streams[eye], &th[eye], &angles_at, &timing, &opts)?;
            let name = format!("frames/{}_{k:06}.png", if eye == 0 { "left" } else { "right" });
            let p = dir.join(&name);
            save_png(&img.gray_image(), &p).map_err(|e| io(&p, &e))?;
            names[eye] = name;
        }
        let [left, right] = names;
        frames.push(FrameRecord { seq: k as u64, t_start_ns: ns(t_start), exposure_ns, left, right });
    }
    progress("render", spec.frames, spec.frames);
    let tp = dir.join("truth/poses.csv");
    std::fs::write(&tp, truth_rows).map_err(|e| io(&tp, &e))?;
    let rolling = spec.readout_ms > 0.0;
    if rolling {
        let tr = dir.join("truth/row_poses.csv");
        std::fs::write(&tr, truth_row_nodes).map_err(|e| io(&tr, &e))?;
    }

    // ---- each eye's FK calibrated as a user would: a simulated calibration dataset of the same unit, fitted
    let method = spec.fk_method;
    for (eye, unit) in units.iter().enumerate() {
        progress("calibrate", eye, 2);
        let d = dir.join(format!("calib/eye{eye}"));
        calibrate_unit(unit, method, spec.calib_step_deg, spec.seed * 7 + eye as u64, spec.seed, &d)?;
    }
    progress("calibrate", 2, 2);

    let meta = SessionMeta {
        format: SESSION_FORMAT.into(),
        description: format!(
            "synthetic: scene {SCENE_GENERATOR} seed {}, units sim-{} / sim-{}, {} frames at {} fps, readout {} ms, \
             exposure {} ms, pursuit up to {} deg/s, FK calibrated with {}",
            spec.seed,
            spec.seed * 2 + 11,
            spec.seed * 2 + 12,
            spec.frames,
            spec.fps,
            spec.readout_ms,
            spec.exposure_ms,
            spec.pursuit_deg_s,
            spec.fk_method
        ) + &if spec.fixation_m == DEFAULT_TARGET_DEPTH_M {
            String::new()
        } else {
            format!(", fixations at {}-{} m", spec.fixation_m[0], spec.fixation_m[1])
        },
        readout_ms: spec.readout_ms,
        exposure_ms: Some(spec.exposure_ms),
        time_offset_ms: None,
        width: spec.width,
        height: spec.height,
        fps: spec.fps,
        loop_period_ns: Some((period * 1e9).round() as i64),
        stereo: "calib/stereo.yaml".into(),
        fk: ["calib/eye0".into(), "calib/eye1".into()],
        gravity: [0.0, 1.0, 0.0],
        truth: Some(Truth {
            units: ["truth/unit0.toml".into(), "truth/unit1.toml".into()],
            scene_generator: SCENE_GENERATOR.into(),
            scene_seed: spec.seed,
            stereo: "truth/stereo.yaml".into(),
            poses: "truth/poses.csv".into(),
            row_poses: rolling.then(|| "truth/row_poses.csv".into()),
        }),
    };
    Session::write_index(dir, &meta, &frames, &encoders)
}

/// Rotation helper for tests: a rotation matrix from Fick degrees.
pub fn fick(deg: [f64; 3]) -> Matrix3<f64> {
    Fick::from_deg(deg).to_matrix()
}
