//! The physical effects of `shared/spec/effects.md`: one parameter struct each, [`Effects`]
//! (a unit's set) and [`Effect`] (their binding names, switches and parameter vectors).
use super::*;

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

/// hinge_backlash: clearance in the passive hinges, "the platform settles differently depending
/// on the direction from which each link last approached" (effects.md). The spec's sentence reads
/// three ways, each its own parameters (all clearances >= 0, deg; any mix may be on):
/// - `backlash_deg`: a lag of each link: leg i acts as if its link angle were shifted by
///   -/+ half its clearance after the link last moved +/- (the clearance seen at the input);
/// - `hinge_lag_deg`: a lag of the platform about each leg's platform hinge axis: the platform
///   settles rotated about that axis (`R_P v_i`, base frame) by -/+ half the leg's clearance,
///   signed by the direction link i last moved (the clearance seen at the platform, per hinge);
/// - `platform_lag_deg`: direction-dependent settling of the platform as a whole: it lags its own
///   last motion (the nine hinges' clearances seen together, whatever mix of links moved it).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HingeBacklash {
    pub enabled: bool,
    /// Full clearance per leg; the leg settles at -/+ half of it after moving +/-.
    pub backlash_deg: [f64; 3],
    /// The platform lags its last motion by this angle (deg, >= 0): rotated by it about the
    /// direction of that motion, backwards.
    pub platform_lag_deg: f64,
    /// Full clearance per leg at its platform hinge: after link i last moved +/-, the platform
    /// sits rotated by -/+ half of it about that hinge's axis (unit files before it load as 0).
    pub hinge_lag_deg: [f64; 3],
}

/// The three readings of hinge_backlash, as parameter subsets of [`Effect::HingeBacklash`]
/// (indices into its parameter vector): what the discrepancy workflow fits one at a time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BacklashForm {
    /// `backlash_deg`: a lag of each link.
    LinkLag,
    /// `hinge_lag_deg`: a lag of the platform about each leg's platform hinge axis.
    HingeLag,
    /// `platform_lag_deg`: the platform lags its own last motion.
    PlatformLag,
}

impl BacklashForm {
    pub const ALL: [BacklashForm; 3] = [BacklashForm::LinkLag, BacklashForm::HingeLag, BacklashForm::PlatformLag];

    /// Indices of this form's parameters in [`Effect::param_names`] of hinge_backlash.
    pub fn indices(self) -> std::ops::Range<usize> {
        match self {
            BacklashForm::LinkLag => 0..3,
            BacklashForm::PlatformLag => 3..4,
            BacklashForm::HingeLag => 4..7,
        }
    }

    pub fn describe(self) -> &'static str {
        match self {
            BacklashForm::LinkLag => "a lag of each link (backlash_deg)",
            BacklashForm::HingeLag => "a lag of the platform about each leg's platform hinge axis (hinge_lag_deg)",
            BacklashForm::PlatformLag => "the platform lagging its own last motion (platform_lag_deg)",
        }
    }
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

    /// Comma-separated effect names, "all", or "none" (or nothing).
    pub fn parse_list(s: &str) -> Result<Vec<Effect>> {
        match s.trim() {
            "all" => Ok(Effect::ALL.to_vec()),
            "" | "none" => Ok(vec![]),
            _ => s.split(',').map(|n| Effect::from_name(n.trim())).collect(),
        }
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
            Effect::HingeBacklash => {
                [per_leg("backlash_deg"), vec!["platform_lag_deg".into()], per_leg("hinge_lag_deg")].concat()
            }
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

impl std::fmt::Display for Effect {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn effect_lists_by_name_all_or_none() {
        assert_eq!(Effect::parse_list(" all ").unwrap(), Effect::ALL.to_vec());
        assert!(Effect::parse_list("none").unwrap().is_empty() && Effect::parse_list(" ").unwrap().is_empty());
        let two = format!("{}, {}", Effect::ALL[0].name(), Effect::ALL[2].name());
        assert_eq!(Effect::parse_list(&two).unwrap(), vec![Effect::ALL[0], Effect::ALL[2]]);
        assert!(Effect::parse_list("gear_wobble").unwrap_err().to_string().contains("unknown effect 'gear_wobble'"));
    }
}
