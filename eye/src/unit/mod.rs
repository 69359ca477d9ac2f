//! The unit model: a real eye = the nominal geometry + the physical effects of
//! `shared/spec/effects.md`, each by its binding name, with documented parameters and units,
//! each switchable. The simulator draws units of this form, the calibration fits it, the
//! discrepancy workflow extends it and the runtime evaluates it: there is no second copy.
//!
//! ## The true forward kinematics (readings -> camera pose relative to home)
//! For encoder readings `q_i` (deg, already homed), a motion history (the direction each link
//! last moved) and gravity `g` (unit vector in B):
//! 1. link angle:
//!    `theta_i = q_i (1 + encoder_scale_i) + encoder_zero_offset_i - eps [sin(s_i + q_i - phi) - sin(s_i - phi)]`.
//!    The last term is code_wheel_eccentricity: the wheel is
//!    off-centre by `e`, `eps = e / wheel_radius`, `s_i` is the head's position on the wheel (its
//!    marker) and phi the direction of the offset; it is zero at home because homing re-zeroes it.
//!    It is fitted per head (`eps sin(s_i - phi)`, `eps cos(s_i - phi)` free for each head), so
//!    heads placed anywhere on the wheel are described ([`CodeWheelEccentricity`]).
//! 2. hinge_backlash: `theta_i -= dir_i * backlash_i / 2` (`dir_i` = +1 if link i last moved
//!    in +, -1 if in -; the platform settles on the side it was pushed from); after step 3 the
//!    platform also lags its own last motion: `R_P <- exp(-lag u) R_P`, `u` the unit axis of
//!    the last platform rotation between samples (B); and it settles about each leg's platform
//!    hinge axis: `R_P <- exp(-sum_i dir_i hinge_lag_i / 2 (R_P v_i)) R_P` ([`HingeBacklash`]);
//! 3. SPM with per-leg link_angle_error (d1, d2), input_axis_tilt and platform_axis_error ->
//!    platform orientation `R_P` (working mode, Newton);
//! 4. gravity_sag: `R_P <- exp(rad((R_P a) x g)) R_P`, `a` the sag vector in P (deg);
//! 5. camera_mount: `T_C = (R_P, 0) . (R_m, t_m)`;
//! 6. `T_rel = T_C(home)^-1 . T_C`, home = readings 0, direction +1 (homing ends moving +),
//!    gravity [0, 1, 0] (head upright when the home images are taken).
//!
//! encoder_time_offset and measurement_noise do not change this map: the first is applied
//! where encoder samples meet camera frames ([`UnitModel::encoder_time_for_camera`]), the
//! second by the simulator to measured poses.
use crate::encoder::{COUNTS_PER_REV, MARKER_COUNTS};
use crate::error::{EyeError, Result};
use crate::pose::{exp_so3, Fick, Pose};
use crate::spm::{LegParams, SpmGeometry, NOMINAL_D1_DEG, NOMINAL_D2_DEG, NOMINAL_PSI_DEG};
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};
use std::path::Path;

pub const FORMAT: &str = "abvs-unit/1";

mod effects;
mod fk;
pub use effects::*;
pub use fk::*;

fn check_limit(name: &str, v: f64, lim: f64) -> std::result::Result<(), String> {
    if !v.is_finite() {
        return Err(format!("{name}: not a finite number"));
    }
    if v.abs() > lim {
        return Err(format!("{name}: {v} is beyond the plausible limit +-{lim}"));
    }
    Ok(())
}

/// Why [`UnitModel::validate`] refuses a unit model: the field and its implausible value.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct ImplausibleUnit(pub String);

/// A unit (one real eye), as stored in its TOML file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UnitModel {
    /// Always "abvs-unit/1".
    pub format: String,
    pub name: String,
    #[serde(default)]
    pub geometry: NominalGeometry,
    #[serde(default)]
    pub effects: Effects,
}

impl Default for UnitModel {
    fn default() -> Self {
        UnitModel::nominal()
    }
}

fn arr_mut<const N: usize>(a: &mut [f64; N]) -> impl Iterator<Item = &mut f64> {
    a.iter_mut()
}

impl UnitModel {
    /// The nominal eye: design geometry, every effect off.
    pub fn nominal() -> Self {
        UnitModel {
            format: FORMAT.into(),
            name: "nominal".into(),
            geometry: NominalGeometry::default(),
            effects: Effects::default(),
        }
    }

    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| EyeError::io(path, e))?;
        Self::from_toml_str(&text, path)
    }

    pub fn from_toml_str(text: &str, path: &Path) -> Result<Self> {
        let u: UnitModel =
            toml::from_str(text).map_err(|e| EyeError::Unit { path: path.into(), msg: e.to_string() })?;
        u.validate().map_err(|e| EyeError::Unit { path: path.into(), msg: e.0 })?;
        Ok(u)
    }

    pub fn to_toml_string(&self) -> String {
        let body = toml::to_string(self).expect("unit model serialises");
        format!(
            "# abvs unit model (shared/spec/effects.md names; degrees, millimetres, micrometres).\n\
             # Each [effects.<name>] has `enabled`; a disabled effect's parameters are ignored.\n{body}"
        )
    }

    pub fn save(&self, path: &Path) -> Result<()> {
        std::fs::write(path, self.to_toml_string()).map_err(|e| EyeError::io(path, e))
    }

    /// Plausibility limits: values far outside any physical unit are refused with the field.
    pub fn validate(&self) -> std::result::Result<(), ImplausibleUnit> {
        self.check_plausible().map_err(ImplausibleUnit)
    }

    fn check_plausible(&self) -> std::result::Result<(), String> {
        if self.format != FORMAT {
            return Err(format!("format is '{}', expected '{FORMAT}'", self.format));
        }
        let g = &self.geometry;
        let geometry = [
            ("geometry.d1_deg", g.d1_deg, NOMINAL_D1_DEG, 20.0),
            ("geometry.d2_deg", g.d2_deg, NOMINAL_D2_DEG, 20.0),
            ("geometry.psi_deg", g.psi_deg[0], NOMINAL_PSI_DEG[0], 30.0),
            ("geometry.psi_deg", g.psi_deg[1], NOMINAL_PSI_DEG[1], 30.0),
            ("geometry.psi_deg", g.psi_deg[2], NOMINAL_PSI_DEG[2], 30.0),
        ];
        for (name, v, nominal, lim) in geometry {
            // the limit is on the deviation; the message gives the value the file holds
            if !v.is_finite() {
                return Err(format!("{name}: not a finite number"));
            }
            if (v - nominal).abs() > lim {
                return Err(format!("{name}: {v} is beyond the plausible range {nominal} +-{lim}"));
            }
        }
        for eff in Effect::ALL {
            let (names, values, limits) = (eff.param_names(), self.params(eff), eff.param_limits());
            for ((n, v), lim) in names.iter().zip(values).zip(limits) {
                check_limit(&format!("effects.{eff}.{n}"), v, lim)?;
            }
        }
        let e = &self.effects;
        check_limit(
            "effects.code_wheel_eccentricity.eccentricity_um",
            e.code_wheel_eccentricity.eccentricity_um,
            500.0,
        )?;
        check_limit("effects.code_wheel_eccentricity.phase_deg", e.code_wheel_eccentricity.phase_deg, 720.0)?;
        let r = e.code_wheel_eccentricity.wheel_radius_mm;
        if !(r.is_finite() && r > 1.0 && r < 100.0) {
            return Err(format!("effects.code_wheel_eccentricity.wheel_radius_mm: {r} must be in (1, 100) mm"));
        }
        if e.hinge_backlash.backlash_deg.iter().any(|b| *b < 0.0) {
            return Err("effects.hinge_backlash.backlash_deg: must be >= 0".into());
        }
        if e.hinge_backlash.hinge_lag_deg.iter().any(|b| *b < 0.0) {
            return Err("effects.hinge_backlash.hinge_lag_deg: must be >= 0".into());
        }
        if e.hinge_backlash.platform_lag_deg < 0.0 {
            return Err("effects.hinge_backlash.platform_lag_deg: must be >= 0".into());
        }
        if e.measurement_noise.rot_deg < 0.0 || e.measurement_noise.trans_mm < 0.0 {
            return Err("effects.measurement_noise: sigmas must be >= 0".into());
        }
        Ok(())
    }

    pub fn is_enabled(&self, e: Effect) -> bool {
        let x = &self.effects;
        match e {
            Effect::EncoderZeroOffset => x.encoder_zero_offset.enabled,
            Effect::LinkAngleError => x.link_angle_error.enabled,
            Effect::InputAxisTilt => x.input_axis_tilt.enabled,
            Effect::PlatformAxisError => x.platform_axis_error.enabled,
            Effect::CameraMount => x.camera_mount.enabled,
            Effect::CodeWheelEccentricity => x.code_wheel_eccentricity.enabled,
            Effect::EncoderScale => x.encoder_scale.enabled,
            Effect::HingeBacklash => x.hinge_backlash.enabled,
            Effect::GravitySag => x.gravity_sag.enabled,
            Effect::EncoderTimeOffset => x.encoder_time_offset.enabled,
            Effect::MeasurementNoise => x.measurement_noise.enabled,
        }
    }

    pub fn set_enabled(&mut self, e: Effect, on: bool) {
        let x = &mut self.effects;
        match e {
            Effect::EncoderZeroOffset => x.encoder_zero_offset.enabled = on,
            Effect::LinkAngleError => x.link_angle_error.enabled = on,
            Effect::InputAxisTilt => x.input_axis_tilt.enabled = on,
            Effect::PlatformAxisError => x.platform_axis_error.enabled = on,
            Effect::CameraMount => x.camera_mount.enabled = on,
            Effect::CodeWheelEccentricity => x.code_wheel_eccentricity.enabled = on,
            Effect::EncoderScale => x.encoder_scale.enabled = on,
            Effect::HingeBacklash => x.hinge_backlash.enabled = on,
            Effect::GravitySag => x.gravity_sag.enabled = on,
            Effect::EncoderTimeOffset => x.encoder_time_offset.enabled = on,
            Effect::MeasurementNoise => x.measurement_noise.enabled = on,
        }
    }

    /// The effects switched on, in [`Effect::ALL`] order.
    pub fn enabled_effects(&self) -> Vec<Effect> {
        Effect::ALL.into_iter().filter(|e| self.is_enabled(*e)).collect()
    }

    /// Parameters of one effect as a vector (order of [`Effect::param_names`]).
    pub fn params(&self, e: Effect) -> Vec<f64> {
        let x = &self.effects;
        match e {
            Effect::EncoderZeroOffset => x.encoder_zero_offset.offset_deg.to_vec(),
            Effect::LinkAngleError => [x.link_angle_error.d1_error_deg, x.link_angle_error.d2_error_deg].concat(),
            Effect::InputAxisTilt => [x.input_axis_tilt.tilt_x_deg, x.input_axis_tilt.tilt_y_deg].concat(),
            Effect::PlatformAxisError => {
                [x.platform_axis_error.azimuth_deg, x.platform_axis_error.elevation_deg].concat()
            }
            Effect::CameraMount => [x.camera_mount.rotation_deg, x.camera_mount.offset_mm].concat(),
            Effect::CodeWheelEccentricity => {
                let h = x.code_wheel_eccentricity.per_head_um();
                [h.map(|v| v[0]), h.map(|v| v[1])].concat()
            }
            Effect::EncoderScale => x.encoder_scale.relative_error.to_vec(),
            Effect::HingeBacklash => {
                let b = &x.hinge_backlash;
                [b.backlash_deg.to_vec(), vec![b.platform_lag_deg], b.hinge_lag_deg.to_vec()].concat()
            }
            Effect::GravitySag => x.gravity_sag.sag_deg.to_vec(),
            Effect::EncoderTimeOffset => vec![x.encoder_time_offset.latency_ms],
            Effect::MeasurementNoise => {
                vec![x.measurement_noise.rot_deg, x.measurement_noise.trans_mm]
            }
        }
    }

    /// Sets the parameters of one effect from a vector (order of [`Effect::param_names`]).
    pub fn set_params(&mut self, e: Effect, p: &[f64]) -> Result<()> {
        let n = e.param_names().len();
        if p.len() != n {
            return Err(EyeError::Invalid(format!("{e}: {} parameters given, {n} expected", p.len())));
        }
        let x = &mut self.effects;
        let mut it = p.iter().copied();
        let mut fill = |dst: &mut dyn Iterator<Item = &mut f64>| {
            for d in dst {
                *d = it.next().unwrap();
            }
        };
        match e {
            Effect::EncoderZeroOffset => fill(&mut arr_mut(&mut x.encoder_zero_offset.offset_deg)),
            Effect::LinkAngleError => {
                let l = &mut x.link_angle_error;
                fill(&mut arr_mut(&mut l.d1_error_deg).chain(arr_mut(&mut l.d2_error_deg)))
            }
            Effect::InputAxisTilt => {
                let l = &mut x.input_axis_tilt;
                fill(&mut arr_mut(&mut l.tilt_x_deg).chain(arr_mut(&mut l.tilt_y_deg)))
            }
            Effect::PlatformAxisError => {
                let l = &mut x.platform_axis_error;
                fill(&mut arr_mut(&mut l.azimuth_deg).chain(arr_mut(&mut l.elevation_deg)))
            }
            Effect::CameraMount => {
                let l = &mut x.camera_mount;
                fill(&mut arr_mut(&mut l.rotation_deg).chain(arr_mut(&mut l.offset_mm)))
            }
            Effect::CodeWheelEccentricity => {
                let c = &mut x.code_wheel_eccentricity;
                let h: [[f64; 2]; 3] = std::array::from_fn(|i| [p[i], p[3 + i]]);
                // The wheel-level summary: the heads' mean amplitude, the phase seen by head 1.
                c.eccentricity_um = h.iter().map(|v| v[0].hypot(v[1])).sum::<f64>() / 3.0;
                let s1 = MARKER_COUNTS[0] as f64 * 360.0 / COUNTS_PER_REV as f64;
                c.phase_deg = (s1 - h[0][1].atan2(h[0][0]).to_degrees()).rem_euclid(360.0);
                c.head_um = Some(h);
            }
            Effect::EncoderScale => fill(&mut arr_mut(&mut x.encoder_scale.relative_error)),
            Effect::HingeBacklash => {
                let b = &mut x.hinge_backlash;
                fill(
                    &mut arr_mut(&mut b.backlash_deg)
                        .chain(std::iter::once(&mut b.platform_lag_deg))
                        .chain(arr_mut(&mut b.hinge_lag_deg)),
                )
            }
            Effect::GravitySag => fill(&mut arr_mut(&mut x.gravity_sag.sag_deg)),
            Effect::EncoderTimeOffset => x.encoder_time_offset.latency_ms = p[0],
            Effect::MeasurementNoise => {
                x.measurement_noise.rot_deg = p[0];
                x.measurement_noise.trans_mm = p[1];
            }
        }
        Ok(())
    }

    /// Camera time (s) at which an encoder sample stamped `t_enc` (s) was read.
    pub fn encoder_time_for_camera(&self, t_enc: f64) -> f64 {
        let e = &self.effects.encoder_time_offset;
        if e.enabled {
            t_enc - e.latency_ms * 1e-3
        } else {
            t_enc
        }
    }

    /// Builds the evaluator of this unit's true FK.
    pub fn compile(&self) -> Result<UnitFk> {
        UnitFk::new(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nominal_unit_is_nominal_fk() {
        let fk = UnitModel::nominal().compile().unwrap();
        let p = fk.p6(&[10.0, -5.0, 20.0], &Conditions::default()).unwrap();
        let r = SpmGeometry::nominal().fk_cold(&[10f64, -5.0, 20.0].map(f64::to_radians)).unwrap().r;
        let f = Fick::from_matrix(&r).to_deg();
        for k in 0..3 {
            assert!((p[k] - f[k]).abs() < 1e-10);
            assert!(p[3 + k].abs() < 1e-12);
        }
    }

    #[test]
    fn toml_round_trip_and_param_vectors() {
        let mut u = UnitModel::nominal();
        for e in Effect::ALL {
            let n = e.param_names().len();
            let p: Vec<f64> = (0..n).map(|k| 0.01 * (k as f64 + 1.0)).collect();
            u.set_params(e, &p).unwrap();
            u.set_enabled(e, true);
            let back = u.params(e);
            for (a, b) in p.iter().zip(&back) {
                assert!((a - b).abs() < 1e-12, "{e}: {p:?} vs {back:?}");
            }
        }
        let text = u.to_toml_string();
        let v = UnitModel::from_toml_str(&text, Path::new("x.toml")).unwrap();
        assert_eq!(u, v);
    }

    #[test]
    fn bad_unit_file_names_field() {
        let text = "format = \"abvs-unit/1\"\nname = \"x\"\n[effects.camera_mount]\nenabled = true\noffset_mm = [0.0, 0.0, 900.0]\n";
        let err = UnitModel::from_toml_str(text, Path::new("u.toml")).unwrap_err().to_string();
        assert!(err.contains("u.toml") && err.contains("offset_mm"), "{err}");
        let err = UnitModel::from_toml_str(
            "format = \"abvs-unit/1\"\nname = \"x\"\n[effects.warp_drive]\n",
            Path::new("u.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("warp_drive"), "{err}");
    }

    #[test]
    fn home_is_identity_for_any_unit() {
        let mut u = UnitModel::nominal();
        u.effects.camera_mount =
            CameraMount { enabled: true, rotation_deg: [2.0, -1.0, 1.5], offset_mm: [1.0, -2.0, 8.0] };
        u.effects.encoder_zero_offset = EncoderZeroOffset { enabled: true, offset_deg: [0.5, -0.3, 0.2] };
        u.effects.gravity_sag = GravitySag { enabled: true, sag_deg: [0.05, 0.0, 0.02] };
        let fk = u.compile().unwrap();
        let p = fk.p6(&[0.0; 3], &Conditions::default()).unwrap();
        assert!(p.iter().all(|x| x.abs() < 1e-12), "{p:?}");
    }

    #[test]
    fn backlash_depends_on_direction() {
        let mut u = UnitModel::nominal();
        u.effects.hinge_backlash = HingeBacklash { enabled: true, backlash_deg: [0.1, 0.1, 0.1], ..Default::default() };
        let fk = u.compile().unwrap();
        let q = [5.0, 5.0, 5.0];
        let up = fk.p6(&q, &Conditions { dir: [1.0; 3], ..Default::default() }).unwrap();
        let down = fk.p6(&q, &Conditions { dir: [-1.0; 3], ..Default::default() }).unwrap();
        // equal links: pure roll, shifted by the full clearance between directions
        assert!((up[1] - down[1] + 0.1).abs() < 1e-9, "{up:?} {down:?}");
    }

    #[test]
    fn platform_lags_its_last_motion() {
        let mut u = UnitModel::nominal();
        u.effects.hinge_backlash = HingeBacklash { enabled: true, platform_lag_deg: 0.05, ..Default::default() };
        let fk = u.compile().unwrap();
        let nominal = UnitModel::nominal().compile().unwrap();
        // Reach the same reading from two sides: the platform sits behind each motion by the lag.
        let target = [8.0, -3.0, 5.0];
        let mut a = fk.stream();
        fk.next(&mut a, &[0.0, -6.0, 2.0], [0.0, 1.0, 0.0]).unwrap();
        let pa = fk.next(&mut a, &target, [0.0, 1.0, 0.0]).unwrap();
        let mut b = fk.stream();
        fk.next(&mut b, &[16.0, 0.0, 8.0], [0.0, 1.0, 0.0]).unwrap();
        let pb = fk.next(&mut b, &target, [0.0, 1.0, 0.0]).unwrap();
        let p0 = nominal.next(&mut nominal.stream(), &target, [0.0, 1.0, 0.0]).unwrap();
        let (da, db) = (crate::pose::rotation_angle_deg(&pa.r, &p0.r), crate::pose::rotation_angle_deg(&pb.r, &p0.r));
        // Relative to home (which lags along +z): both differ from nominal, from each other by ~2 lags.
        assert!(da > 0.01 && db > 0.01, "{da} {db}");
        let ab = crate::pose::rotation_angle_deg(&pa.r, &pb.r);
        assert!((ab - 0.1).abs() < 0.02, "{ab}");
    }

    /// The hinge reading of backlash: reached from the two sides of every link, the platform
    /// differs by the full clearance about each hinge axis; home carries the + side.
    #[test]
    fn platform_settles_about_each_hinge_axis() {
        let mut u = UnitModel::nominal();
        u.effects.hinge_backlash =
            HingeBacklash { enabled: true, hinge_lag_deg: [0.08, 0.0, 0.0], ..Default::default() };
        let fk = u.compile().unwrap();
        let q = [6.0, -4.0, 9.0];
        let up = fk.pose(&q, &Conditions { dir: [1.0; 3], ..Default::default() }, None).unwrap().0;
        let down = fk.pose(&q, &Conditions { dir: [-1.0, 1.0, 1.0], ..Default::default() }, None).unwrap().0;
        // The two differ by 0.08 deg about leg 1's platform hinge axis (the other legs' flips do not matter).
        let w = crate::pose::rotation_vector(&(down.r * up.r.transpose())).map(f64::to_degrees);
        assert!((w.norm() - 0.08).abs() < 1e-6, "{w:?}");
        let other = fk.pose(&q, &Conditions { dir: [1.0, -1.0, -1.0], ..Default::default() }, None).unwrap().0;
        assert!(crate::pose::rotation_vector(&(other.r * up.r.transpose())).norm() < 1e-12);
        // Reloaded from a file without the field, a unit has none of it (older files load).
        let old = "format = \"abvs-unit/1\"\nname = \"x\"\n[effects.hinge_backlash]\nenabled = true\nbacklash_deg = [0.1, 0.1, 0.1]\nplatform_lag_deg = 0.02\n";
        let v = UnitModel::from_toml_str(old, Path::new("u.toml")).unwrap();
        assert_eq!(v.effects.hinge_backlash.hinge_lag_deg, [0.0; 3]);
        let mut bad = u.clone();
        bad.effects.hinge_backlash.hinge_lag_deg[2] = -0.01;
        assert!(bad.validate().unwrap_err().0.contains("hinge_lag_deg"));
    }

    /// The per-head form describes the wheel exactly (heads at their markers), and any other
    /// head placement: heads 120 deg apart read `eps sin(s_i + q - phi)` minus its home value.
    #[test]
    fn eccentricity_per_head_form() {
        let mut wheel = UnitModel::nominal();
        wheel.set_enabled(Effect::CodeWheelEccentricity, true);
        wheel.effects.code_wheel_eccentricity.eccentricity_um = 25.0;
        wheel.effects.code_wheel_eccentricity.phase_deg = 40.0;
        let mut heads = wheel.clone();
        let p = wheel.params(Effect::CodeWheelEccentricity);
        heads.set_params(Effect::CodeWheelEccentricity, &p).unwrap();
        assert!(heads.effects.code_wheel_eccentricity.head_um.is_some());
        let q = [17.0, -23.0, 31.0];
        let dir = [1.0; 3];
        let (a, b) = (wheel.compile().unwrap().link_angles(&q, &dir), heads.compile().unwrap().link_angles(&q, &dir));
        for i in 0..3 {
            assert!((a[i] - b[i]).abs() < 1e-15, "{a:?} {b:?}");
        }
        // Heads at 90, 210, 330 deg on the wheel (another placement): one amplitude, any phase.
        let (eps, phi) = (25e-3 / WHEEL_RADIUS_MM, 40f64.to_radians());
        let s: [f64; 3] = [90f64, 210.0, 330.0].map(f64::to_radians);
        let h: Vec<f64> =
            (0..6).map(|k| 25.0 * if k < 3 { (s[k] - phi).cos() } else { (s[k - 3] - phi).sin() }).collect();
        heads.set_params(Effect::CodeWheelEccentricity, &h).unwrap();
        assert!((heads.effects.code_wheel_eccentricity.eccentricity_um - 25.0).abs() < 1e-9);
        let t = heads.compile().unwrap().link_angles(&q, &dir);
        for i in 0..3 {
            let qr = q[i].to_radians();
            let want = qr - eps * ((s[i] + qr - phi).sin() - (s[i] - phi).sin());
            assert!((t[i] - want).abs() < 1e-15, "head {i}: {} vs {want}", t[i]);
        }
        // The per-head form survives the unit file.
        let back = UnitModel::from_toml_str(&heads.to_toml_string(), Path::new("u.toml")).unwrap();
        assert_eq!(back.effects.code_wheel_eccentricity.head_um, heads.effects.code_wheel_eccentricity.head_um);
    }
}
