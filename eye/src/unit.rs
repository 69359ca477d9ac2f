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
//!    the last platform rotation between samples (B);
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

/// The design geometry (conventions.md); a unit deviates from it only through effects.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NominalGeometry {
    /// Proximal link arc (deg).
    pub d1_deg: f64,
    /// Distal link arc (deg).
    pub d2_deg: f64,
    /// Home azimuths of the proximal links (deg).
    pub psi_deg: [f64; 3],
}

impl Default for NominalGeometry {
    fn default() -> Self {
        NominalGeometry { d1_deg: NOMINAL_D1_DEG, d2_deg: NOMINAL_D2_DEG, psi_deg: NOMINAL_PSI_DEG }
    }
}

/// encoder_zero_offset: the homing marker of a link is not where the model assumes.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EncoderZeroOffset {
    pub enabled: bool,
    /// Added to each link's reading (deg).
    pub offset_deg: [f64; 3],
}

/// link_angle_error: proximal (d1) and distal (d2) link arcs off nominal, per leg.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LinkAngleError {
    pub enabled: bool,
    pub d1_error_deg: [f64; 3],
    pub d2_error_deg: [f64; 3],
}

/// input_axis_tilt: a proximal link's axis is not coaxial; per leg, rotations about x then y
/// of B (deg) applied to that link's axis and its distal-joint axis.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct InputAxisTilt {
    pub enabled: bool,
    pub tilt_x_deg: [f64; 3],
    pub tilt_y_deg: [f64; 3],
}

/// platform_axis_error: a platform joint axis off its nominal direction, per leg (deg).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PlatformAxisError {
    pub enabled: bool,
    /// In the platform plane, about the platform normal.
    pub azimuth_deg: [f64; 3],
    /// Out of the platform plane.
    pub elevation_deg: [f64; 3],
}

/// camera_mount: the camera frame C in the platform frame P.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CameraMount {
    pub enabled: bool,
    /// Fick angles [alpha, beta, gamma] of C relative to P (deg).
    pub rotation_deg: [f64; 3],
    /// Optical centre in P, i.e. its offset from the spherical centre O1 (mm).
    pub offset_mm: [f64; 3],
}

/// code_wheel_eccentricity: the shared wheel is mounted off-centre by `eccentricity_um` towards
/// azimuth `phase_deg` (wheel angle); a head at wheel angle w reads an extra
/// `eps sin(w - phase)` with `eps = eccentricity / wheel_radius`.
///
/// Where each read head sits on the wheel is a design fact the spec leaves open (ours: at its
/// link's marker), so the effect is fitted per head: head i reads an extra
/// `(x_i sin q_i + y_i (cos q_i - 1)) / wheel_radius` (`head_um[i] = [x_i, y_i]`, um at the code
/// track, zero at home). For one eccentric wheel every head sees the same amplitude
/// `hypot(x_i, y_i) = eccentricity_um`, at a phase set by the head's position; absent,
/// `head_um` follows from `eccentricity_um`, `phase_deg` and the heads at their markers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CodeWheelEccentricity {
    pub enabled: bool,
    pub eccentricity_um: f64,
    pub phase_deg: f64,
    /// Radius of the code track (mm); a design constant, not fitted.
    pub wheel_radius_mm: f64,
    /// Per-head form (see above); when present it overrides `eccentricity_um` / `phase_deg`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub head_um: Option<[[f64; 2]; 3]>,
}

/// Code-track radius of the 1448-line wheel (mm): 20 um of eccentricity is ~0.1 deg.
pub const WHEEL_RADIUS_MM: f64 = 11.5;

impl CodeWheelEccentricity {
    /// Each head's `[x_i, y_i]` (um): the per-head form, or the one wheel's seen by heads at
    /// their markers.
    pub fn per_head_um(&self) -> [[f64; 2]; 3] {
        self.head_um.unwrap_or_else(|| {
            std::array::from_fn(|i| {
                let s = MARKER_COUNTS[i] as f64 * std::f64::consts::TAU / COUNTS_PER_REV as f64;
                let a = s - self.phase_deg.to_radians();
                [self.eccentricity_um * a.cos(), self.eccentricity_um * a.sin()]
            })
        })
    }
}

impl Default for CodeWheelEccentricity {
    fn default() -> Self {
        CodeWheelEccentricity {
            enabled: false,
            eccentricity_um: 0.0,
            phase_deg: 0.0,
            wheel_radius_mm: WHEEL_RADIUS_MM,
            head_um: None,
        }
    }
}

/// encoder_scale: effective counts per revolution differ from 92672 (relative error per link).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EncoderScale {
    pub enabled: bool,
    /// theta = reading * (1 + relative_error).
    pub relative_error: [f64; 3],
}

/// hinge_backlash: clearance in the passive hinges. It shows two ways: per leg, as an
/// equivalent link-angle clearance that depends on the direction each link last moved, and at
/// the platform, which settles behind its own last motion (the clearances of all nine hinges
/// seen together, whatever mix of links produced the motion).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HingeBacklash {
    pub enabled: bool,
    /// Full clearance per leg; the leg settles at -/+ half of it after moving +/-.
    pub backlash_deg: [f64; 3],
    /// The platform lags its last motion by this angle (deg, >= 0): rotated by it about the
    /// direction of that motion, backwards.
    pub platform_lag_deg: f64,
}

/// gravity_sag: elastic deflection under the platform's and camera's weight.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GravitySag {
    pub enabled: bool,
    /// Moment-arm vector in P scaled by the compliance (deg per unit gravity): the sag rotation
    /// is `(R_P a) x g` (deg, base frame).
    pub sag_deg: [f64; 3],
}

/// encoder_time_offset: the encoder clock lags the camera clock by a constant latency.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EncoderTimeOffset {
    pub enabled: bool,
    /// An encoder sample stamped t was read at camera time t - latency (ms).
    pub latency_ms: f64,
}

/// measurement_noise: scatter of the AprilGrid pose measurement (1-sigma per axis).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MeasurementNoise {
    pub enabled: bool,
    pub rot_deg: f64,
    pub trans_mm: f64,
}

/// All effects of effects.md, by their binding names.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Effects {
    pub encoder_zero_offset: EncoderZeroOffset,
    pub link_angle_error: LinkAngleError,
    pub input_axis_tilt: InputAxisTilt,
    pub platform_axis_error: PlatformAxisError,
    pub camera_mount: CameraMount,
    pub code_wheel_eccentricity: CodeWheelEccentricity,
    pub encoder_scale: EncoderScale,
    pub hinge_backlash: HingeBacklash,
    pub gravity_sag: GravitySag,
    pub encoder_time_offset: EncoderTimeOffset,
    pub measurement_noise: MeasurementNoise,
}

/// The effects by name, for generic code (fitting, the discrepancy workflow, the CLI).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Effect {
    EncoderZeroOffset,
    LinkAngleError,
    InputAxisTilt,
    PlatformAxisError,
    CameraMount,
    CodeWheelEccentricity,
    EncoderScale,
    HingeBacklash,
    GravitySag,
    EncoderTimeOffset,
    MeasurementNoise,
}

impl Effect {
    pub const ALL: [Effect; 11] = [
        Effect::EncoderZeroOffset,
        Effect::LinkAngleError,
        Effect::InputAxisTilt,
        Effect::PlatformAxisError,
        Effect::CameraMount,
        Effect::CodeWheelEccentricity,
        Effect::EncoderScale,
        Effect::HingeBacklash,
        Effect::GravitySag,
        Effect::EncoderTimeOffset,
        Effect::MeasurementNoise,
    ];

    /// The binding snake_case name of effects.md.
    pub fn name(self) -> &'static str {
        match self {
            Effect::EncoderZeroOffset => "encoder_zero_offset",
            Effect::LinkAngleError => "link_angle_error",
            Effect::InputAxisTilt => "input_axis_tilt",
            Effect::PlatformAxisError => "platform_axis_error",
            Effect::CameraMount => "camera_mount",
            Effect::CodeWheelEccentricity => "code_wheel_eccentricity",
            Effect::EncoderScale => "encoder_scale",
            Effect::HingeBacklash => "hinge_backlash",
            Effect::GravitySag => "gravity_sag",
            Effect::EncoderTimeOffset => "encoder_time_offset",
            Effect::MeasurementNoise => "measurement_noise",
        }
    }

    pub fn from_name(s: &str) -> Result<Effect> {
        Effect::ALL.into_iter().find(|e| e.name() == s).ok_or_else(|| {
            EyeError::Invalid(format!("unknown effect '{s}' (known: {})", Effect::ALL.map(|e| e.name()).join(", ")))
        })
    }

    /// Names and units of the parameters exposed to fitting, in vector order.
    /// code_wheel_eccentricity is fitted per head in Cartesian form (linear near zero, no phase
    /// wrap, any head placement).
    pub fn param_names(self) -> Vec<String> {
        let per_leg = |p: &str| (1..=3).map(|i| format!("{p}.{i}")).collect::<Vec<_>>();
        match self {
            Effect::EncoderZeroOffset => per_leg("offset_deg"),
            Effect::LinkAngleError => [per_leg("d1_error_deg"), per_leg("d2_error_deg")].concat(),
            Effect::InputAxisTilt => [per_leg("tilt_x_deg"), per_leg("tilt_y_deg")].concat(),
            Effect::PlatformAxisError => [per_leg("azimuth_deg"), per_leg("elevation_deg")].concat(),
            Effect::CameraMount => [
                "rotation_deg.alpha",
                "rotation_deg.beta",
                "rotation_deg.gamma",
                "offset_mm.x",
                "offset_mm.y",
                "offset_mm.z",
            ]
            .map(String::from)
            .to_vec(),
            Effect::CodeWheelEccentricity => [per_leg("head_x_um"), per_leg("head_y_um")].concat(),
            Effect::EncoderScale => per_leg("relative_error"),
            Effect::HingeBacklash => [per_leg("backlash_deg"), vec!["platform_lag_deg".into()]].concat(),
            Effect::GravitySag => ["sag_deg.x", "sag_deg.y", "sag_deg.z"].map(String::from).to_vec(),
            Effect::EncoderTimeOffset => vec!["latency_ms".into()],
            Effect::MeasurementNoise => vec!["rot_deg".into(), "trans_mm".into()],
        }
    }

    /// Whether the effect changes the static map readings -> pose (and so can be fitted from
    /// a static dataset).
    pub fn is_kinematic(self) -> bool {
        !matches!(self, Effect::EncoderTimeOffset | Effect::MeasurementNoise)
    }

    /// Hard plausibility limits of the parameters (same order as [`Effect::param_names`]):
    /// values beyond them describe no physical unit. [`UnitModel::validate`] refuses them and
    /// fitting keeps its iterates inside them.
    pub fn param_limits(self) -> Vec<f64> {
        let lim = match self {
            Effect::EncoderZeroOffset => 20.0,
            Effect::LinkAngleError | Effect::InputAxisTilt | Effect::PlatformAxisError => 5.0,
            Effect::CameraMount => return vec![30.0, 30.0, 30.0, 50.0, 50.0, 50.0],
            Effect::CodeWheelEccentricity => 500.0,
            Effect::EncoderScale => 0.05,
            Effect::HingeBacklash | Effect::GravitySag => 2.0,
            Effect::EncoderTimeOffset => 1000.0,
            Effect::MeasurementNoise => return vec![5.0, 20.0],
        };
        vec![lim; self.param_names().len()]
    }
}

fn check_limit(name: &str, v: f64, lim: f64) -> std::result::Result<(), String> {
    if !v.is_finite() {
        return Err(format!("{name}: not a finite number"));
    }
    if v.abs() > lim {
        return Err(format!("{name}: {v} is beyond the plausible limit +-{lim}"));
    }
    Ok(())
}

impl std::fmt::Display for Effect {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
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
            ("geometry.d1_deg", g.d1_deg - NOMINAL_D1_DEG, 20.0),
            ("geometry.d2_deg", g.d2_deg - NOMINAL_D2_DEG, 20.0),
            ("geometry.psi_deg", g.psi_deg[0] - NOMINAL_PSI_DEG[0], 30.0),
            ("geometry.psi_deg", g.psi_deg[1] - NOMINAL_PSI_DEG[1], 30.0),
            ("geometry.psi_deg", g.psi_deg[2] - NOMINAL_PSI_DEG[2], 30.0),
        ];
        for (name, v, lim) in geometry {
            check_limit(name, v, lim)?;
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
                [x.hinge_backlash.backlash_deg.to_vec(), vec![x.hinge_backlash.platform_lag_deg]].concat()
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
                fill(&mut arr_mut(&mut b.backlash_deg).chain(std::iter::once(&mut b.platform_lag_deg)))
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

/// Conditions of one sample beyond the readings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Conditions {
    /// Direction each link last moved (+1 / -1).
    pub dir: [f64; 3],
    /// Gravity in B (unit vector).
    pub gravity: [f64; 3],
    /// Direction (unit rotation axis in B) of the platform's last motion; homing ends with a
    /// positive roll, so +z before any other motion.
    pub platform_dir: [f64; 3],
}

impl Default for Conditions {
    fn default() -> Self {
        Conditions { dir: [1.0; 3], gravity: [0.0, 1.0, 0.0], platform_dir: [0.0, 0.0, 1.0] }
    }
}

/// Smallest platform rotation between samples (rad) that counts as a motion for the platform
/// lag: well below one encoder count's effect, well above Newton's round-off.
const PLATFORM_MOTION_RAD: f64 = 1e-6;

/// Tracks the direction each link last moved, from readings in acquisition order. A link that
/// did not move keeps its previous direction; before any motion it is + (homing ends moving +).
#[derive(Debug, Clone, Default)]
pub struct MotionHistory {
    last: Option<[f64; 3]>,
    dir: [f64; 3],
}

impl MotionHistory {
    pub fn new() -> Self {
        MotionHistory { last: None, dir: [1.0; 3] }
    }
    /// Feeds the next reading (deg) and returns the direction state for it.
    pub fn update(&mut self, reading_deg: &[f64; 3]) -> [f64; 3] {
        let half_count = 0.5 * 360.0 / COUNTS_PER_REV as f64;
        if let Some(last) = self.last {
            for i in 0..3 {
                let d = reading_deg[i] - last[i];
                if d.abs() > half_count {
                    self.dir[i] = d.signum();
                }
            }
        }
        self.last = Some(*reading_deg);
        self.dir
    }
}

/// The compiled true FK of a unit (see the module doc for the map).
#[derive(Debug, Clone)]
pub struct UnitFk {
    pub model: UnitModel,
    pub geom: SpmGeometry,
    mount: Pose,
    home_inv: Pose,
    home_r: Matrix3<f64>,
    /// Per head: the reading error's sin and (cos - 1) coefficients (rad).
    ecc: [(f64, f64); 3],
}

impl UnitFk {
    pub fn new(model: &UnitModel) -> Result<Self> {
        model.validate().map_err(|e| EyeError::Invalid(e.0))?;
        let e = &model.effects;
        let g = &model.geometry;
        let mut legs = [LegParams::nominal(0), LegParams::nominal(1), LegParams::nominal(2)];
        for (i, l) in legs.iter_mut().enumerate() {
            l.psi_deg = g.psi_deg[i];
            l.d1_deg = g.d1_deg;
            l.d2_deg = g.d2_deg;
            if e.link_angle_error.enabled {
                l.d1_deg += e.link_angle_error.d1_error_deg[i];
                l.d2_deg += e.link_angle_error.d2_error_deg[i];
            }
            if e.input_axis_tilt.enabled {
                l.axis_tilt_deg = [e.input_axis_tilt.tilt_x_deg[i], e.input_axis_tilt.tilt_y_deg[i]];
            }
            if e.platform_axis_error.enabled {
                l.platform_axis_deg = [e.platform_axis_error.azimuth_deg[i], e.platform_axis_error.elevation_deg[i]];
            }
        }
        let geom = SpmGeometry::from_params(&legs);
        let mount = if e.camera_mount.enabled {
            let m = &e.camera_mount;
            Pose::new(Fick::from_deg(m.rotation_deg).to_matrix(), Vector3::from(m.offset_mm))
        } else {
            Pose::identity()
        };
        let c = &e.code_wheel_eccentricity;
        let ecc = if c.enabled {
            let h = c.per_head_um();
            std::array::from_fn(|i| (h[i][0] * 1e-3 / c.wheel_radius_mm, h[i][1] * 1e-3 / c.wheel_radius_mm))
        } else {
            [(0.0, 0.0); 3]
        };
        let mut fk =
            UnitFk { model: model.clone(), geom, mount, home_inv: Pose::identity(), home_r: Matrix3::identity(), ecc };
        let (home_c, home_r) = fk.camera_in_base(&[0.0; 3], &Conditions::default(), None)?;
        fk.home_inv = home_c.inverse();
        fk.home_r = home_r;
        Ok(fk)
    }

    /// Platform orientation at home (for warm starts).
    pub fn home_platform(&self) -> Matrix3<f64> {
        self.home_r
    }

    /// True link angles (rad) for readings (deg) and directions (step 1-2 of the module doc).
    pub fn link_angles(&self, reading_deg: &[f64; 3], dir: &[f64; 3]) -> [f64; 3] {
        let e = &self.model.effects;
        let mut th = [0.0; 3];
        for i in 0..3 {
            let q = reading_deg[i].to_radians();
            let mut t = q;
            if e.encoder_scale.enabled {
                t *= 1.0 + e.encoder_scale.relative_error[i];
            }
            if e.encoder_zero_offset.enabled {
                t += e.encoder_zero_offset.offset_deg[i].to_radians();
            }
            let (ex, ey) = self.ecc[i];
            if ex != 0.0 || ey != 0.0 {
                t -= ex * q.sin() + ey * (q.cos() - 1.0);
            }
            if e.hinge_backlash.enabled {
                t -= dir[i] * 0.5 * e.hinge_backlash.backlash_deg[i].to_radians();
            }
            th[i] = t;
        }
        th
    }

    /// Camera pose in B and the platform orientation (for warm starts).
    fn camera_in_base(
        &self,
        reading_deg: &[f64; 3],
        cond: &Conditions,
        warm: Option<&Matrix3<f64>>,
    ) -> Result<(Pose, Matrix3<f64>)> {
        let r = self.platform(reading_deg, &cond.dir, warm, true)?;
        Ok((self.camera_from_platform(&r, cond), r))
    }

    /// Platform orientation of the mechanism (steps 1-3 of the module doc), before the platform
    /// lag and the sag: the state the next sample warm-starts from.
    fn platform(
        &self,
        reading_deg: &[f64; 3],
        dir: &[f64; 3],
        warm: Option<&Matrix3<f64>>,
        check: bool,
    ) -> Result<Matrix3<f64>> {
        let th = self.link_angles(reading_deg, dir);
        let sol = match warm {
            Some(r0) => self.geom.fk_from(&th, r0).or_else(|_| self.geom.fk_cold(&th))?,
            None => self.geom.fk_cold(&th)?,
        };
        if check {
            self.geom.check_singularity(&sol.r, &th)?;
        }
        Ok(sol.r)
    }

    /// Camera pose in B from the mechanism's platform orientation: platform lag, sag, mount.
    fn camera_from_platform(&self, r: &Matrix3<f64>, cond: &Conditions) -> Pose {
        let mut rp = *r;
        let lag = self.model.effects.hinge_backlash.platform_lag_deg;
        if self.model.effects.hinge_backlash.enabled && lag != 0.0 {
            rp = exp_so3(&(Vector3::from(cond.platform_dir) * -lag.to_radians())) * rp;
        }
        let sag = &self.model.effects.gravity_sag;
        if sag.enabled {
            let a = Vector3::from(sag.sag_deg).map(f64::to_radians);
            let d = (rp * a).cross(&Vector3::from(cond.gravity));
            rp = exp_so3(&d) * rp;
        }
        Pose::new(rp, Vector3::zeros()).compose(&self.mount)
    }

    /// Camera pose relative to home for readings (deg). Returns the pose and the platform
    /// orientation to warm-start the next call with.
    pub fn pose(
        &self,
        reading_deg: &[f64; 3],
        cond: &Conditions,
        warm: Option<&Matrix3<f64>>,
    ) -> Result<(Pose, Matrix3<f64>)> {
        let (c, r) = self.camera_in_base(reading_deg, cond, warm)?;
        Ok((self.home_inv.compose(&c), r))
    }

    /// As [`UnitFk::pose`] without the singularity check (still the working mode): for a
    /// solver's intermediate candidates; its answer is checked with [`UnitFk::pose`] or
    /// [`UnitFk::next`].
    pub fn pose_unchecked(
        &self,
        reading_deg: &[f64; 3],
        cond: &Conditions,
        warm: Option<&Matrix3<f64>>,
    ) -> Result<(Pose, Matrix3<f64>)> {
        let r = self.platform(reading_deg, &cond.dir, warm, false)?;
        Ok((self.home_inv.compose(&self.camera_from_platform(&r, cond)), r))
    }

    /// `P = [alpha, beta, gamma (deg), x, y, z (mm)]` for one reading.
    pub fn p6(&self, reading_deg: &[f64; 3], cond: &Conditions) -> Result<[f64; 6]> {
        Ok(self.pose(reading_deg, cond, Some(&self.home_r))?.0.to_p6())
    }

    /// A new stream of readings in acquisition order (one per eye): see [`UnitFk::next`].
    pub fn stream(&self) -> UnitStream {
        UnitStream { hist: MotionHistory::new(), warm: self.home_r, platform_dir: [0.0, 0.0, 1.0] }
    }

    /// The next reading of a stream -> camera pose relative to home. The reading updates the
    /// motion history (backlash direction) even if the pose fails, as the links did move; the
    /// warm start advances only on success.
    pub fn next(&self, st: &mut UnitStream, reading_deg: &[f64; 3], gravity: [f64; 3]) -> Result<Pose> {
        let warm = st.warm;
        self.next_from(st, reading_deg, gravity, &warm)
    }

    /// As [`UnitFk::next`], with the mechanism's Newton started from `start` (a platform
    /// orientation near the answer) instead of the stream's last one; same result, fewer
    /// iterations after a large move.
    pub fn next_from(
        &self,
        st: &mut UnitStream,
        reading_deg: &[f64; 3],
        gravity: [f64; 3],
        start: &Matrix3<f64>,
    ) -> Result<Pose> {
        let dir = st.hist.update(reading_deg);
        let (cond, r) = self.step(st, reading_deg, dir, gravity, start, true)?;
        st.platform_dir = cond.platform_dir;
        st.warm = r;
        Ok(self.home_inv.compose(&self.camera_from_platform(&r, &cond)))
    }

    /// The conditions (link directions, platform motion direction, gravity) and the platform
    /// orientation that [`UnitFk::next`] would give the reading, without advancing the stream:
    /// for solvers that try candidate readings (calibrated IK) and then evaluate them with
    /// [`UnitFk::pose_unchecked`] under these conditions. `start`: where the mechanism's Newton
    /// starts (a platform orientation near the answer; default the stream's last one). Like
    /// `pose_unchecked`, it checks the working mode but not the singularity margin.
    pub fn peek(
        &self,
        st: &UnitStream,
        reading_deg: &[f64; 3],
        gravity: [f64; 3],
        start: Option<&Matrix3<f64>>,
    ) -> Result<(Conditions, Matrix3<f64>)> {
        let dir = st.hist.clone().update(reading_deg);
        self.step(st, reading_deg, dir, gravity, start.unwrap_or(&st.warm), false)
    }

    /// Platform orientation and conditions of the stream's next reading (shared by next and peek).
    fn step(
        &self,
        st: &UnitStream,
        reading_deg: &[f64; 3],
        dir: [f64; 3],
        gravity: [f64; 3],
        start: &Matrix3<f64>,
        check: bool,
    ) -> Result<(Conditions, Matrix3<f64>)> {
        let r = self.platform(reading_deg, &dir, Some(start), check)?;
        let w = crate::pose::rotation_vector(&(r * st.warm.transpose()));
        let platform_dir = if w.norm() > PLATFORM_MOTION_RAD { (w / w.norm()).into() } else { st.platform_dir };
        Ok((Conditions { dir, gravity, platform_dir }, r))
    }

    /// Predicted poses for a dataset, walking it in acquisition order so motion history
    /// (backlash) and per-sample gravity are applied as recorded. Errors name the sample.
    pub fn predict_dataset(&self, data: &crate::dataset::Dataset) -> Result<Vec<[f64; 6]>> {
        let mut st = self.stream();
        data.samples
            .iter()
            .map(|s| {
                self.next(&mut st, &s.theta_deg, s.gravity_or_default())
                    .map(|p| p.to_p6())
                    .map_err(|e| EyeError::Invalid(format!("sample seq {}: {e}", s.seq)))
            })
            .collect()
    }
}

/// Per-stream state of a unit's true FK: the motion history and the previous platform
/// orientation (warm start).
#[derive(Debug, Clone)]
pub struct UnitStream {
    hist: MotionHistory,
    warm: Matrix3<f64>,
    platform_dir: [f64; 3],
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
        u.effects.hinge_backlash =
            HingeBacklash { enabled: true, backlash_deg: [0.1, 0.1, 0.1], platform_lag_deg: 0.0 };
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
        u.effects.hinge_backlash = HingeBacklash { enabled: true, backlash_deg: [0.0; 3], platform_lag_deg: 0.05 };
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
