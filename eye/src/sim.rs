//! The data-collection simulator: draws plausible units and reproduces the paper's protocol
//! (commanded Fick grid in serpentine order -> nominal IK -> motors servo until the encoder
//! reading matches -> the true pose from the unit's physics -> measured with noise).
use crate::dataset::{Dataset, Sample};
use crate::encoder::quantize_deg;
use crate::error::{EyeError, Result};
use crate::pose::{exp_so3, rotation_angle_deg, Fick, Pose};
use crate::psc::grid;
use crate::spm::SpmGeometry;
use crate::unit::{Effect, UnitModel};
use nalgebra::Vector3;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

fn signed(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    let m = rng.gen_range(lo..hi);
    if rng.gen_bool(0.5) {
        m
    } else {
        -m
    }
}

/// Draws a plausible unit: every listed effect on, magnitudes in the ranges of effects.md.
/// The same seed gives the same unit.
pub fn draw_unit(seed: u64, effects: &[Effect]) -> UnitModel {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut u = UnitModel::nominal();
    u.name = format!("sim-{seed}");
    // Draw every effect's parameters (fixed order) so a unit's values do not depend on which
    // effects are switched on: the same seed with and without an effect differs only in it.
    let e = &mut u.effects;
    for i in 0..3 {
        e.encoder_zero_offset.offset_deg[i] = signed(&mut rng, 0.1, 1.0);
        e.link_angle_error.d1_error_deg[i] = signed(&mut rng, 0.1, 0.5);
        e.link_angle_error.d2_error_deg[i] = signed(&mut rng, 0.1, 0.5);
        let (m, az) = (rng.gen_range(0.05..0.3), rng.gen_range(0.0..std::f64::consts::TAU));
        e.input_axis_tilt.tilt_x_deg[i] = m * az.cos();
        e.input_axis_tilt.tilt_y_deg[i] = m * az.sin();
        e.platform_axis_error.azimuth_deg[i] = signed(&mut rng, 0.1, 0.5);
        e.platform_axis_error.elevation_deg[i] = signed(&mut rng, 0.1, 0.5);
        e.camera_mount.rotation_deg[i] = signed(&mut rng, 0.5, 3.0);
        e.encoder_scale.relative_error[i] = signed(&mut rng, 1e-4, 1e-3);
        e.hinge_backlash.backlash_deg[i] = rng.gen_range(0.01..0.1);
    }
    // The camera sits in front of the spherical centre: mostly +z, a little off-axis.
    e.camera_mount.offset_mm = [rng.gen_range(-3.0..3.0), rng.gen_range(-3.0..3.0), rng.gen_range(2.0..12.0)];
    e.code_wheel_eccentricity.eccentricity_um = rng.gen_range(5.0..30.0);
    e.code_wheel_eccentricity.phase_deg = rng.gen_range(0.0..360.0);
    // Sag lever: the camera's weight acts forward of O1 (z), with a little lateral offset.
    let m = rng.gen_range(0.01..0.1);
    e.gravity_sag.sag_deg = [signed(&mut rng, 0.0, 0.2) * m, signed(&mut rng, 0.0, 0.2) * m, m];
    e.encoder_time_offset.latency_ms = rng.gen_range(0.1..5.0);
    e.measurement_noise.rot_deg = rng.gen_range(0.005..0.02);
    e.measurement_noise.trans_mm = rng.gen_range(0.02..0.1);
    for eff in effects {
        u.set_enabled(*eff, true);
    }
    u
}

/// How the commanded poses are laid out.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Commanded {
    /// Every `step_deg` over alpha +-30, beta +-15, gamma +-30 (the paper's 1 and 3 deg grids).
    Step(f64),
    /// `n` values per axis spanning each range (the paper's n^3 fine-tuning sets).
    PerAxis(usize),
}

/// What to simulate beyond the unit.
#[derive(Debug, Clone)]
pub struct SimSpec {
    pub commanded: Commanded,
    /// Half-ranges of alpha, beta, gamma (deg); the paper's workspace by default.
    pub range_deg: [f64; 3],
    /// Keep only this many commanded poses, drawn at random, visited in random order.
    pub random: Option<usize>,
    pub seed: u64,
    /// Probability that a sample's measurement fails (too few corners) and is absent. The
    /// paper's units reached ~95% of the commanded grid.
    pub dropout: f64,
    /// Gravity in B for the whole session.
    pub gravity: [f64; 3],
}

impl Default for SimSpec {
    fn default() -> Self {
        SimSpec {
            commanded: Commanded::Step(3.0),
            range_deg: crate::WORKSPACE_DEG,
            random: None,
            seed: 0,
            dropout: 0.05,
            gravity: [0.0, 1.0, 0.0],
        }
    }
}

/// Counts of a simulated session.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SimStats {
    pub commanded: usize,
    pub written: usize,
    /// Outside the nominal IK or near its singularities.
    pub unreachable_nominal: usize,
    /// Reachable nominally but unreachable or near-singular for this unit.
    pub unreachable_unit: usize,
    /// Measurement failures (dropout).
    pub failed_measurement: usize,
    /// Largest ideal-vs-measured rotation (deg) and translation (mm) deviation.
    pub max_dev_rot_deg: f64,
    pub max_dev_trans_mm: f64,
}

/// The commanded Fick poses (deg) in acquisition order: serpentine over gamma (fastest), then
/// beta, then alpha, so consecutive poses are neighbours, as a real collection drives them.
pub fn commanded_poses(spec: &SimSpec) -> Vec<[f64; 3]> {
    let axis = |k: usize| -> Vec<f64> {
        let r = spec.range_deg[k];
        match spec.commanded {
            Commanded::Step(s) => grid(-r, r, s),
            Commanded::PerAxis(n) if n >= 2 => (0..n).map(|i| -r + 2.0 * r * i as f64 / (n - 1) as f64).collect(),
            Commanded::PerAxis(_) => vec![0.0],
        }
    };
    let (al, be, ga) = (axis(0), axis(1), axis(2));
    let mut out = Vec::with_capacity(al.len() * be.len() * ga.len());
    let mut row = 0usize;
    for (ia, a) in al.iter().enumerate() {
        let bs: Vec<f64> = if ia % 2 == 0 { be.clone() } else { be.iter().rev().copied().collect() };
        for b in bs {
            let gs: Vec<f64> = if row % 2 == 0 { ga.clone() } else { ga.iter().rev().copied().collect() };
            row += 1;
            for g in gs {
                out.push([*a, b, g]);
            }
        }
    }
    out
}

/// Simulates one session of the paper's protocol. `progress(done, total)` is called now and then.
pub fn simulate_dataset(
    unit: &UnitModel,
    spec: &SimSpec,
    mut progress: impl FnMut(usize, usize),
) -> Result<(Dataset, SimStats)> {
    if !(0.0..1.0).contains(&spec.dropout) {
        return Err(EyeError::Invalid(format!("dropout {} must be in [0, 1)", spec.dropout)));
    }
    let gn = Vector3::from(spec.gravity).norm();
    if (gn - 1.0).abs() > 1e-3 {
        return Err(EyeError::Invalid(format!("gravity {:?} is not a unit vector", spec.gravity)));
    }
    if let Commanded::Step(s) = spec.commanded {
        if !(s.is_finite() && s > 0.0) {
            return Err(EyeError::Invalid(format!("step {s} deg must be > 0")));
        }
    }
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    let mut poses = commanded_poses(spec);
    if let Some(n) = spec.random {
        poses.shuffle(&mut rng);
        poses.truncate(n);
    }
    let nominal = SpmGeometry::nominal();
    let fk = unit.compile()?;
    let noise = &unit.effects.measurement_noise;
    let (nr, nt) = if noise.enabled { (noise.rot_deg.to_radians(), noise.trans_mm) } else { (0.0, 0.0) };
    let n_rot = Normal::new(0.0, nr).map_err(|e| EyeError::Invalid(e.to_string()))?;
    let n_tr = Normal::new(0.0, nt).map_err(|e| EyeError::Invalid(e.to_string()))?;

    let mut stats = SimStats { commanded: poses.len(), ..Default::default() };
    let mut stream = fk.stream();
    let mut samples = Vec::new();
    let mut t = 0.0f64;
    let mut last_reading = [0.0f64; 3];
    let total = poses.len();
    for (k, cmd) in poses.iter().enumerate() {
        if k % 4096 == 0 {
            progress(k, total);
        }
        // The random draws happen for every commanded pose, so dropping one pose never shifts
        // the noise of the others (reproducible subsets).
        let drop_meas = rng.gen_bool(spec.dropout);
        let nrv = Vector3::new(n_rot.sample(&mut rng), n_rot.sample(&mut rng), n_rot.sample(&mut rng));
        let ntv = Vector3::new(n_tr.sample(&mut rng), n_tr.sample(&mut rng), n_tr.sample(&mut rng));

        let r_cmd = Fick::from_deg(*cmd).to_matrix();
        let Ok(th_cmd) = nominal.ik_checked(&r_cmd) else {
            stats.unreachable_nominal += 1;
            continue;
        };
        // Motors servo until each encoder reads the commanded angle, to the count.
        let reading = th_cmd.map(|x| quantize_deg(x.to_degrees()));
        // Travel at ~200 deg/s between poses, then settle and expose.
        let travel = (0..3).map(|i| (reading[i] - last_reading[i]).abs()).fold(0.0, f64::max);
        t += travel / 200.0 + 0.25;
        last_reading = reading;
        let Ok(truth) = fk.next(&mut stream, &reading, spec.gravity) else {
            stats.unreachable_unit += 1;
            continue;
        };
        if drop_meas {
            stats.failed_measurement += 1;
            continue;
        }
        let meas = Pose::new(exp_so3(&nrv) * truth.r, truth.t + ntv);
        stats.max_dev_rot_deg = stats.max_dev_rot_deg.max(rotation_angle_deg(&r_cmd, &meas.r));
        stats.max_dev_trans_mm = stats.max_dev_trans_mm.max(meas.t.norm());
        samples.push(Sample {
            seq: k as u64,
            t_s: (t * 1e6).round() / 1e6,
            theta_deg: reading,
            pose: meas.to_p6(),
            cmd_deg: Some(*cmd),
            gravity: Some(spec.gravity),
            extra: vec![],
        });
    }
    progress(total, total);
    stats.written = samples.len();
    Ok((Dataset { samples, extra_columns: vec![] }, stats))
}

/// The repeatability protocol of ISO 9283 as the paper ran it: every target is approached
/// `approaches` times (30), each time from a random start drawn over the workspace; at the
/// target the links stand still while the camera is measured `images` times.
#[derive(Debug, Clone)]
pub struct RepeatSpec {
    /// Commanded target orientations (Fick, deg); [`iso9283_targets`] by default.
    pub targets: Vec<[f64; 3]>,
    /// Approaches per target, each from its own random start.
    pub approaches: usize,
    /// Measurements (images) per approach, the links standing still: their scatter is the
    /// measurement noise alone, which lets the repeatability tool remove it.
    pub images: usize,
    /// The motor servo stops within this many counts of each commanded count (uniform
    /// integer error per link and approach; 2 counts = 0.0078 deg, the paper's "encoder
    /// readings within +-0.01 deg").
    pub settle_counts: i64,
    /// Measurement noise (1-sigma rotation deg, translation mm) instead of the unit's own,
    /// e.g. for a laser tracker: ISO 9283 asks for a measurement well below the repeatability.
    pub measurement: Option<(f64, f64)>,
    pub seed: u64,
    pub gravity: [f64; 3],
    /// Half-ranges (deg) of the random starts.
    pub range_deg: [f64; 3],
}

/// ISO 9283's five test poses mapped to the eye's Fick workspace: P1 at the centre, P2..P5 at
/// 80% of each half-range on the diagonal plane alpha/30 = gamma/30 (corners (+,+,+), (+,-,+),
/// (-,+,-), (-,-,-)).
pub fn iso9283_targets(range_deg: [f64; 3]) -> Vec<[f64; 3]> {
    let r = range_deg.map(|v| 0.8 * v);
    vec![[0.0, 0.0, 0.0], [r[0], r[1], r[2]], [r[0], -r[1], r[2]], [-r[0], r[1], -r[2]], [-r[0], -r[1], -r[2]]]
}

impl Default for RepeatSpec {
    fn default() -> Self {
        RepeatSpec {
            targets: iso9283_targets(crate::WORKSPACE_DEG),
            approaches: 30,
            images: 10,
            settle_counts: 2,
            measurement: None,
            seed: 0,
            gravity: [0.0, 1.0, 0.0],
            range_deg: crate::WORKSPACE_DEG,
        }
    }
}

/// Extra columns of a repeatability session: 1-based target, approach and image indices.
pub const REPEAT_COLUMNS: [&str; 3] = ["target", "approach", "image"];

/// A simulated repeatability session: the measured dataset (one row per image, with the
/// [`REPEAT_COLUMNS`]) and the same rows with the true, noise-free poses.
#[derive(Debug, Clone, PartialEq)]
pub struct RepeatSession {
    pub measured: Dataset,
    pub truth: Dataset,
}

/// Simulates an ISO 9283 repeatability session ([`RepeatSpec`]): for each target, `approaches`
/// times: drive to a random start (nominal IK, servo), then to the target (nominal IK, the servo
/// stopping within `settle_counts`), the true pose from the unit's physics with the motion
/// history of that path (backlash: each link's approach direction), measured `images` times.
/// Same seed, same session.
pub fn simulate_repeatability(unit: &UnitModel, spec: &RepeatSpec) -> Result<RepeatSession> {
    if spec.approaches < 2 || spec.images < 1 || spec.targets.is_empty() {
        return Err(EyeError::Invalid(format!(
            "repeatability needs targets, at least 2 approaches and 1 image (got {} targets, {} approaches, {} images)",
            spec.targets.len(),
            spec.approaches,
            spec.images
        )));
    }
    if spec.settle_counts < 0 {
        return Err(EyeError::Invalid(format!("settle_counts {} must be >= 0", spec.settle_counts)));
    }
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    let nominal = SpmGeometry::nominal();
    let fk = unit.compile()?;
    let (nr, nt) = match spec.measurement {
        Some(m) => m,
        None => {
            let n = &unit.effects.measurement_noise;
            if n.enabled {
                (n.rot_deg, n.trans_mm)
            } else {
                (0.0, 0.0)
            }
        }
    };
    let bad = |e: rand_distr::NormalError| EyeError::Invalid(format!("measurement noise: {e}"));
    let (n_rot, n_tr) = (Normal::new(0.0, nr.to_radians()).map_err(bad)?, Normal::new(0.0, nt).map_err(bad)?);
    let count = 360.0 / crate::encoder::COUNTS_PER_REV as f64;
    let mut stream = fk.stream();
    let (mut measured, mut truth) = (Dataset::default(), Dataset::default());
    for d in [&mut measured, &mut truth] {
        d.extra_columns = REPEAT_COLUMNS.map(String::from).to_vec();
    }
    let (mut t, mut seq, mut last) = (0.0f64, 0u64, [0.0f64; 3]);
    let mut travel = |to: &[f64; 3], t: &mut f64| {
        let d = (0..3).map(|i| (to[i] - last[i]).abs()).fold(0.0, f64::max);
        *t += d / 200.0 + 0.25;
        last = *to;
    };
    for (ti, target) in spec.targets.iter().enumerate() {
        let th_cmd = nominal
            .ik_checked(&Fick::from_deg(*target).to_matrix())
            .map_err(|e| EyeError::Invalid(format!("target {} {target:?} deg: no nominal IK: {e}", ti + 1)))?;
        let cmd = th_cmd.map(|x| quantize_deg(x.to_degrees()));
        for a in 0..spec.approaches {
            // A random start the unit reaches (drawn again when it does not).
            let mut tries = 0;
            loop {
                tries += 1;
                let f = [0, 1, 2].map(|k| rng.gen_range(-spec.range_deg[k]..=spec.range_deg[k]));
                let Ok(th) = nominal.ik_checked(&Fick::from_deg(f).to_matrix()) else { continue };
                let start = th.map(|x| quantize_deg(x.to_degrees()));
                let mut probe = stream.clone();
                if fk.next(&mut probe, &start, spec.gravity).is_ok() {
                    stream = probe;
                    travel(&start, &mut t);
                    break;
                }
                if tries > 1000 {
                    return Err(EyeError::Invalid("no reachable random start in 1000 draws".into()));
                }
            }
            let reading: [f64; 3] = std::array::from_fn(|i| {
                cmd[i] + rng.gen_range(-spec.settle_counts..=spec.settle_counts) as f64 * count
            });
            travel(&reading, &mut t);
            let pose = fk.next(&mut stream, &reading, spec.gravity).map_err(|e| {
                EyeError::Invalid(format!("target {} {target:?} deg unreachable for the unit: {e}", ti + 1))
            })?;
            for im in 0..spec.images {
                let nrv = Vector3::new(n_rot.sample(&mut rng), n_rot.sample(&mut rng), n_rot.sample(&mut rng));
                let ntv = Vector3::new(n_tr.sample(&mut rng), n_tr.sample(&mut rng), n_tr.sample(&mut rng));
                let meas = Pose::new(exp_so3(&nrv) * pose.r, pose.t + ntv);
                let extra = vec![(ti + 1).to_string(), (a + 1).to_string(), (im + 1).to_string()];
                let row = |p: &Pose| Sample {
                    seq,
                    t_s: (t * 1e6).round() / 1e6,
                    theta_deg: reading,
                    pose: p.to_p6(),
                    cmd_deg: Some(*target),
                    gravity: Some(spec.gravity),
                    extra: extra.clone(),
                };
                measured.samples.push(row(&meas));
                truth.samples.push(row(&pose));
                seq += 1;
                t += 0.04;
            }
        }
    }
    Ok(RepeatSession { measured, truth })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn serpentine_neighbours() {
        let spec = SimSpec { commanded: Commanded::Step(3.0), ..Default::default() };
        let p = commanded_poses(&spec);
        assert_eq!(p.len(), 21 * 11 * 21);
        for w in p.windows(2) {
            let d: f64 = (0..3).map(|k| (w[0][k] - w[1][k]).abs()).sum();
            assert!(d <= 3.0 + 1e-9, "{:?} -> {:?}", w[0], w[1]);
        }
        let spec = SimSpec { commanded: Commanded::PerAxis(7), ..Default::default() };
        assert_eq!(commanded_poses(&spec).len(), 343);
    }

    #[test]
    fn reproducible_bit_for_bit() {
        let u = draw_unit(3, &Effect::ALL);
        let spec = SimSpec { commanded: Commanded::Step(10.0), seed: 9, ..Default::default() };
        let (a, sa) = simulate_dataset(&u, &spec, |_, _| {}).unwrap();
        let (b, sb) = simulate_dataset(&u, &spec, |_, _| {}).unwrap();
        assert_eq!(a, b);
        assert_eq!(sa, sb);
        assert!(sa.written > 0);
    }

    #[test]
    fn plausible_unit_deviates_by_degrees_and_millimetres() {
        let u = draw_unit(1, &Effect::ALL);
        let spec = SimSpec { commanded: Commanded::Step(6.0), dropout: 0.0, ..Default::default() };
        let (_, s) = simulate_dataset(&u, &spec, |_, _| {}).unwrap();
        assert!(s.max_dev_rot_deg > 1.0 && s.max_dev_rot_deg < 15.0, "{s:?}");
        assert!(s.max_dev_trans_mm > 1.0 && s.max_dev_trans_mm < 20.0, "{s:?}");
    }
}
