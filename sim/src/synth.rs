//! Synthetic sessions with ground truth (`abvs sim session`): the simulator's units moving through saccades
//! and smooth pursuit in a textured 3D scene of known geometry, rendered through the wide-angle lens.
//!
//! - Scene "abvs-scene/1" ([`scene`]): rebuilt from its seed (exact geometry, no mesh files): a back wall,
//!   a floor, a slanted panel, boxes and spheres at 0.35-1.5 m, all with seeded multi-scale noise textures.
//!   World frame = the left eye's home camera frame.
//! - Two units drawn by abvs-eye's simulator (every effect of effects.md on), with a stereo rig at home
//!   (baseline ~65 mm, small rotation).
//! - Motion: both eyes fixate 3D targets in the scene (so they verge), jumping between them with saccades
//!   (minimum-jerk profile, peak speeds up to 1561 deg/s) and following a moving target (smooth pursuit);
//!   the whole motion is periodic, so a looped replay is seamless. The drive commands each eye's orientation
//!   through the nominal IK; the encoders read the link angles (1 kHz, quantised to counts, stamped late by
//!   the unit's encoder_time_offset); the camera moves as the unit's true physics says.
//! - Calibration in the session: each eye's FK fitted by abvs-calib on a simulated calibration dataset of the
//!   same unit (what a user would have), the stereo calibration at home = the true one (issue 5 measures it).
//!
//! Frames are rendered at mid-exposure (no motion blur or rolling shutter: a documented simplification).
use std::path::Path;

use abvs_calib::methods::{fit, FitConfig, Method};
use abvs_calib::model::save_model;
use abvs_camera::{Camera, StereoCalibration};
use abvs_eye::encoder::COUNTS_PER_REV;
use abvs_eye::sim::{draw_unit, simulate_dataset, Commanded, SimSpec};
use abvs_eye::unit::Effect;
use abvs_eye::{Fick, Pose, SpmGeometry, UnitModel};
use abvs_render::{RayTable, RenderOptions, Scene, Surface, Texture};
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use abvs_runtime::error::{Result, RuntimeError};
use abvs_runtime::session::{EncoderRecord, FrameRecord, Session, SessionMeta, Truth, SESSION_FORMAT};

pub const SCENE_GENERATOR: &str = "abvs-scene/1";

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

/// What `abvs sim session` makes.
#[derive(Debug, Clone)]
pub struct SessionSpec {
    pub seed: u64,
    pub frames: usize,
    pub fps: f64,
    pub exposure_ms: f64,
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

/// A gaze plan: fixation targets (3D, world) and when the eyes move between them.
struct Gaze {
    /// (start time s, duration s, from, to, pursuit velocity m/s during the fixation that follows)
    segments: Vec<Segment>,
    period: f64,
}

struct Segment {
    t0: f64,
    saccade_s: f64,
    from: Vector3<f64>,
    to: Vector3<f64>,
    pursuit: Vector3<f64>,
    end: f64,
}

impl Gaze {
    fn plan(rng: &mut ChaCha8Rng, period: f64) -> Gaze {
        let target = |rng: &mut ChaCha8Rng| {
            Vector3::new(rng.gen_range(-0.3..0.3), rng.gen_range(-0.22..0.2), rng.gen_range(0.55..1.3))
        };
        let first = target(rng);
        let mut segments = Vec::new();
        let mut t = 0.0;
        let mut cur = first;
        loop {
            let fix = rng.gen_range(0.15..0.35f64).min(period * 0.6);
            let last = t + fix + 0.12 > period - 0.2;
            let next = if last { first } else { target(rng) };
            let pursuit = if !last && rng.gen_bool(0.4) {
                Vector3::new(rng.gen_range(-0.15..0.15), rng.gen_range(-0.08..0.08), 0.0)
            } else {
                Vector3::zeros()
            };
            // the pursued target drifts during the fixation; the saccade starts from where it got to
            let from = cur;
            // saccade duration from its amplitude: peak speed grows with amplitude up to the eyes' 1561 deg/s
            let amp: f64 = (from + pursuit * fix).angle(&next).to_degrees().max(1.0);
            let vpeak = (200.0 + 40.0 * amp).min(1561.0);
            let saccade_s = (1.875 * amp / vpeak).max(0.025);
            let end = if last { period } else { (t + fix + saccade_s).min(period) };
            segments.push(Segment { t0: t, saccade_s, from, to: next, pursuit, end });
            cur = next;
            t = end;
            if last {
                break;
            }
        }
        Gaze { segments, period }
    }

    /// Target point at time t (s), periodic.
    fn at(&self, t: f64) -> Vector3<f64> {
        let t = t.rem_euclid(self.period);
        let seg = self.segments.iter().find(|s| t < s.end).unwrap_or_else(|| self.segments.last().expect("segments"));
        let fix_end = seg.end - seg.saccade_s;
        if t < fix_end {
            seg.from + seg.pursuit * (t - seg.t0)
        } else {
            let start = seg.from + seg.pursuit * (fix_end - seg.t0);
            let s = ((t - fix_end) / seg.saccade_s).clamp(0.0, 1.0);
            let mj = s * s * s * (10.0 - 15.0 * s + 6.0 * s * s); // minimum jerk
            start + (seg.to - start) * mj
        }
    }
}

/// Fick angles (deg) that point a camera at home pose `home_from_world` at `target` (beta = 0).
fn look_at(home_from_world: &Pose, target: &Vector3<f64>) -> [f64; 3] {
    let d = (home_from_world.r * target + home_from_world.t).normalize();
    [(-d.y).asin().to_degrees(), 0.0, d.x.atan2(d.z).to_degrees()]
}

/// Writes a synthetic session into `dir`. `progress(stage, done, total)`.
pub fn generate(spec: &SessionSpec, dir: &Path, progress: &mut dyn FnMut(&str, usize, usize)) -> Result<()> {
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
    let units: [UnitModel; 2] =
        [draw_unit(spec.seed * 2 + 11, &Effect::ALL), draw_unit(spec.seed * 2 + 12, &Effect::ALL)];
    // stereo rig at home: T_lH^rH (metres inside, mm in the file)
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
    let home_l_to_r = Pose::new(r_home.into_inner(), t_home);
    let world_from_rhome = home_l_to_r.inverse();
    let camera = Camera::ov8856().scaled(spec.width, spec.height);
    let stereo = StereoCalibration {
        left: camera,
        right: camera,
        rotation: r_home.into_inner(),
        translation_mm: t_home * 1000.0,
        rms_px: None,
    };
    let cam_err = |e: abvs_camera::CameraError| inv(e);
    stereo.write_yaml(dir.join("calib/stereo.yaml")).map_err(cam_err)?;
    stereo.write_yaml(dir.join("truth/stereo.yaml")).map_err(cam_err)?;
    for (i, u) in units.iter().enumerate() {
        let p = dir.join(format!("truth/unit{i}.toml"));
        u.save(&p).map_err(|e| io(&p, &e))?;
    }

    // ---- motion and encoders
    let period = spec.frames as f64 / spec.fps;
    let gaze = Gaze::plan(&mut rng, period);
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
        // one period of samples starting 20 ms before the first frame: periodic, so looping is seamless
        let t = k as f64 / spec.encoder_hz - 0.02;
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
    let exposure_ns = (spec.exposure_ms * 1e6) as i64;
    let mut frames = Vec::new();
    let mut truth_rows = String::from("seq,l1,l2,l3,r1,r2,r3\n");
    for k in 0..spec.frames {
        progress("render", k, spec.frames);
        let t_mid = k as f64 / spec.fps;
        let th = [readings(0, t_mid)?, readings(1, t_mid)?];
        truth_rows += &format!(
            "{k},{:.9},{:.9},{:.9},{:.9},{:.9},{:.9}\n",
            th[0][0], th[0][1], th[0][2], th[1][0], th[1][1], th[1][2]
        );
        let mut names = [String::new(), String::new()];
        for eye in 0..2 {
            let rel = fks[eye].next(&mut streams[eye], &th[eye], [0.0, 1.0, 0.0]).map_err(inv)?;
            let rel_m = Pose::new(rel.r, rel.t * 1e-3);
            let world = if eye == 0 { rel_m } else { world_from_rhome.compose(&rel_m) };
            let iso = Isometry3::from_parts(
                Translation3::from(world.t),
                UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(world.r)),
            );
            let opts = RenderOptions {
                supersample: spec.supersample,
                blur_sigma: 0.5,
                vignetting: 0.35,
                gain: if eye == 0 { 1.0 } else { 0.93 },
                offset: if eye == 0 { 0.0 } else { 4.0 },
                noise_sigma: spec.noise_sigma,
                seed: spec.seed * 1_000_003 + (k * 2 + eye) as u64,
                threads: spec.threads,
                ..RenderOptions::default()
            };
            let img = abvs_render::render_with_rays(&scene, &rays, &iso, &opts).map_err(inv)?;
            let name = format!("frames/{}_{k:06}.png", if eye == 0 { "left" } else { "right" });
            let p = dir.join(&name);
            img.gray_image().save(&p).map_err(|e| io(&p, &e))?;
            names[eye] = name;
        }
        let [left, right] = names;
        frames.push(FrameRecord { seq: k as u64, t_start_ns: ns(t_mid) - exposure_ns / 2, exposure_ns, left, right });
    }
    progress("render", spec.frames, spec.frames);
    let tp = dir.join("truth/poses.csv");
    std::fs::write(&tp, truth_rows).map_err(|e| io(&tp, &e))?;

    // ---- each eye's FK calibrated as a user would: a simulated calibration dataset of the same unit, fitted
    let method = spec.fk_method;
    for (eye, unit) in units.iter().enumerate() {
        progress("calibrate", eye, 2);
        let sim = SimSpec {
            commanded: Commanded::Step(spec.calib_step_deg),
            seed: spec.seed * 7 + eye as u64,
            ..SimSpec::default()
        };
        let (data, _) = simulate_dataset(unit, &sim, |_, _| {}).map_err(inv)?;
        let cfg = FitConfig { seed: spec.seed, ..FitConfig::default() };
        let mut parts = fit(method, &data, None, &cfg, &mut |_, _, _, _, _| {}).map_err(inv)?;
        if let Some(u) = parts.unit.as_mut() {
            // encoder latency is not in a static dataset: it comes from the discrepancy workflow (issue 4)
            u.effects.encoder_time_offset = unit.effects.encoder_time_offset.clone();
        }
        let d = dir.join(format!("calib/eye{eye}"));
        save_model(&d, &parts).map_err(|e| io(&d, &e))?;
    }
    progress("calibrate", 2, 2);

    let meta = SessionMeta {
        format: SESSION_FORMAT.into(),
        description: format!(
            "synthetic: scene {SCENE_GENERATOR} seed {}, units sim-{} / sim-{}, {} frames at {} fps, FK calibrated with {}",
            spec.seed,
            spec.seed * 2 + 11,
            spec.seed * 2 + 12,
            spec.frames,
            spec.fps,
            spec.fk_method
        ),
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
        }),
    };
    Session::write_index(dir, &meta, &frames, &encoders)
}

/// Rotation helper for tests: a rotation matrix from Fick degrees.
pub fn fick(deg: [f64; 3]) -> Matrix3<f64> {
    Fick::from_deg(deg).to_matrix()
}
