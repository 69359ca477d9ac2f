//! Per-eye forward kinematics and the moving stereo extrinsic.
//!
//! Each eye's FK comes from its model files: a calibrated `abvs-fk-model/1` directory (any method of
//! abvs-calib) or a unit-model TOML (e.g. the nominal geometry with a measured camera_mount). The pose of each
//! camera relative to its home, T_rel, and the stereo calibration at home give the extrinsic of this instant
//! (conventions.md): T_l^r = T_rel,r^-1 . T_lH^rH . T_rel,l. Runtime poses are in metres.
use std::path::Path;

use abvs_eye::unit::{Conditions, UnitFk, UnitStream};
use abvs_eye::{Pose, UnitModel};
use abvs_fk::model::{FkModel, FkState, Frozen};
use nalgebra::{Matrix3, Vector3};

use crate::tasks::motion::{angle_deg, SPEED_DT_S, WIDE_DT_S};
use abvs_runtime_core::error::{Result, RuntimeError};
use abvs_runtime_core::messages::StereoPose;
use abvs_runtime_core::messages::{FrameMotion, RectifiedCamera, Work};
use abvs_runtime_core::params::MotionConfig;
use abvs_runtime_core::stage::{Stage, StageContext};

/// One eye's FK evaluator with its stream state (motion history for backlash, warm start).
pub enum EyeFk {
    /// A calibrated FK model (abvs-fk-model directory).
    Calibrated {
        /// The model.
        model: Box<FkModel>,
        /// Its stream state.
        state: FkState,
    },
    /// A unit model (a synthetic eye's truth, or the nominal mechanism).
    Unit {
        /// The compiled unit model.
        fk: Box<UnitFk>,
        /// Its stream state.
        state: UnitStream,
    },
}

impl EyeFk {
    /// Loads a model directory (abvs-fk-model) or a unit-model TOML file.
    pub fn load(path: &Path) -> Result<EyeFk> {
        let err = |msg: String| RuntimeError::Model { path: path.to_path_buf(), msg };
        if path.is_dir() {
            let model = FkModel::load(path).map_err(|e| err(e.to_string()))?;
            let state = model.state();
            Ok(EyeFk::Calibrated { model: Box::new(model), state })
        } else if path.is_file() {
            let unit = UnitModel::load(path).map_err(|e| err(e.to_string()))?;
            EyeFk::from_unit(&unit).map_err(|e| err(e.to_string()))
        } else {
            Err(err("no such FK model (expected an abvs-fk-model directory or a unit-model .toml)".into()))
        }
    }

    /// The ideal mechanism (what an uncalibrated eye would use).
    pub fn nominal() -> EyeFk {
        EyeFk::from_unit(&UnitModel::nominal()).expect("the nominal unit model compiles")
    }

    /// The FK of a unit model.
    pub fn from_unit(unit: &UnitModel) -> Result<EyeFk> {
        let fk = unit.compile().map_err(fk_err)?;
        let state = fk.stream();
        Ok(EyeFk::Unit { fk: Box::new(fk), state })
    }

    /// The FK as an [`FkModel`] for the calibrated IK of the gaze controller (the same model files; a unit
    /// model as a physics-only model).
    pub fn ik_model(&self) -> Result<FkModel> {
        match self {
            EyeFk::Calibrated { model, .. } => FkModel::load(&model.dir)
                .map_err(|e| RuntimeError::Model { path: model.dir.clone(), msg: e.to_string() }),
            EyeFk::Unit { fk, .. } => FkModel::from_unit(&fk.model).map_err(fk_err),
        }
    }

    /// The unit model behind a physics-based FK (its encoder latency is applied by time alignment).
    pub fn unit(&self) -> Option<&UnitModel> {
        match self {
            EyeFk::Calibrated { model, .. } => model.unit(),
            EyeFk::Unit { fk, .. } => Some(&fk.model),
        }
    }

    /// Camera pose relative to home (metres) for the next reading of this eye's stream (deg, homed).
    pub fn pose(&mut self, theta_deg: &[f64; 3], gravity: [f64; 3]) -> Result<Pose> {
        let p = match self {
            EyeFk::Calibrated { model, state } => {
                let p6 = model.eval(state, theta_deg, gravity).map_err(fk_err)?;
                Pose::from_p6(&p6)
            }
            EyeFk::Unit { fk, state } => fk.next(state, theta_deg, gravity).map_err(fk_err)?,
        };
        Ok(Pose::new(p.r, p.t * 1e-3))
    }
}

/// An eye's FK with the motion history frozen at its last reading: poses at readings a few milliseconds
/// around it (the rows of a rolling-shutter frame, the speed's central difference) without advancing the
/// stream, so the frame's own pose and the next frame's are what they would be without them.
pub enum FrozenFk<'a> {
    /// A calibrated FK model, frozen.
    Calibrated {
        /// The model.
        model: &'a FkModel,
        /// Its frozen motion history.
        frozen: Frozen,
    },
    /// A unit model, frozen.
    Unit {
        /// The compiled unit model.
        fk: &'a UnitFk,
        /// Its conditions at the last reading.
        cond: Conditions,
        /// The warm start of the solve.
        warm: Matrix3<f64>,
    },
}

impl FrozenFk<'_> {
    /// Camera pose relative to home (metres) at readings `theta_deg` (deg, homed).
    pub fn pose(&mut self, theta_deg: &[f64; 3]) -> Result<Pose> {
        let p = match self {
            FrozenFk::Calibrated { model, frozen } => {
                Pose::from_p6(&model.eval_frozen(frozen, theta_deg).map_err(fk_err)?)
            }
            FrozenFk::Unit { fk, cond, warm } => {
                let (p, r) = fk.pose_unchecked(theta_deg, cond, Some(warm)).map_err(fk_err)?;
                *warm = r;
                p
            }
        };
        Ok(Pose::new(p.r, p.t * 1e-3))
    }
}

impl EyeFk {
    /// The FK frozen at the stream's state for the reading `theta_deg` (the frame's own, already
    /// evaluated with [`EyeFk::pose`]).
    pub fn frozen(&self, theta_deg: &[f64; 3], gravity: [f64; 3]) -> Result<FrozenFk<'_>> {
        Ok(match self {
            EyeFk::Calibrated { model, state } => {
                FrozenFk::Calibrated { model, frozen: model.freeze(state, theta_deg, gravity, None).map_err(fk_err)? }
            }
            EyeFk::Unit { fk, state } => {
                let (cond, warm) = fk.peek(state, theta_deg, gravity, None).map_err(fk_err)?;
                FrozenFk::Unit { fk, cond, warm }
            }
        })
    }
}

/// The moving extrinsic T_l^r = T_rel,r^-1 . T_lH^rH . T_rel,l.
pub fn moving_extrinsic(rel_left: &Pose, rel_right: &Pose, home_left_to_right: &Pose) -> Pose {
    rel_right.inverse().compose(home_left_to_right).compose(rel_left)
}

/// The two eyes' FK and the stereo calibration at home.
pub struct StereoKinematics {
    /// The left eye's FK.
    pub left: EyeFk,
    /// The right eye's FK.
    pub right: EyeFk,
    /// T_lH^rH in metres.
    pub home_left_to_right: Pose,
    /// The gravity direction both eyes' FK are evaluated with (unit vector; +y unless the session says).
    pub gravity: [f64; 3],
}

impl StereoKinematics {
    /// Both eyes' FK and T_lH^rH (rotation, translation in metres); gravity along +y.
    pub fn new(left: EyeFk, right: EyeFk, rotation: Matrix3<f64>, translation_m: Vector3<f64>) -> Self {
        StereoKinematics {
            left,
            right,
            home_left_to_right: Pose::new(rotation, translation_m),
            gravity: [0.0, 1.0, 0.0],
        }
    }

    /// Each eye's encoder latency (s) from its unit model (0 for an FK without one).
    pub fn encoder_latency_s(&self) -> [f64; 2] {
        let latency = |unit: Option<&UnitModel>| unit.map(|u| u.encoder_time_for_camera(0.0).abs()).unwrap_or(0.0);
        [latency(self.left.unit()), latency(self.right.unit())]
    }

    /// Poses for one frame from both eyes' link angles at its mid-exposure time.
    pub fn solve(&mut self, theta_left: &[f64; 3], theta_right: &[f64; 3]) -> Result<StereoPose> {
        let rel_left = self.left.pose(theta_left, self.gravity)?;
        let rel_right = self.right.pose(theta_right, self.gravity)?;
        Ok(StereoPose {
            rel_left,
            rel_right,
            left_to_right: moving_extrinsic(&rel_left, &rel_right, &self.home_left_to_right),
        })
    }
}

/// The rotation vector of a rotation matrix, robust near the identity (where the angle from the trace alone
/// loses its precision, or turns NaN on a matrix a rounding off orthogonal).
pub fn log_so3(m: &Matrix3<f64>) -> Vector3<f64> {
    let v = 0.5 * Vector3::new(m[(2, 1)] - m[(1, 2)], m[(0, 2)] - m[(2, 0)], m[(1, 0)] - m[(0, 1)]);
    let (s, c) = (v.norm(), ((m.trace() - 1.0) / 2.0).clamp(-1.0, 1.0));
    if s < 1e-15 {
        return v;
    }
    v * (s.atan2(c) / s)
}

/// The kinematics stage: both eyes' poses and the moving extrinsic ([`Work::pose`]) from the aligned link
/// angles; the eyes' speeds, the per-row rotations and the motion gate ([`Work::motion`]).
pub struct KinematicsStage {
    /// Both eyes' FK and the home extrinsic.
    pub kin: StereoKinematics,
    /// The per-row correction, the motion gate, a time offset override.
    pub motion: MotionConfig,
    /// Rectified focal length (px): blur in the pixels the disparity engine sees.
    f_out: f64,
}

impl KinematicsStage {
    /// The stage with the default motion settings.
    pub fn new(kin: StereoKinematics) -> Self {
        KinematicsStage { kin, motion: MotionConfig::default(), f_out: 0.0 }
    }

    /// The same stage with other motion settings.
    pub fn with_motion(mut self, motion: MotionConfig) -> Self {
        self.motion = motion;
        self
    }

    /// Speeds, per-row rotations and the gate of one frame (its poses at the frame instant solved).
    fn frame_motion(&mut self, theta: &[[f64; 3]; 2], rel: [&Pose; 2], m: &mut FrameMotion) -> Result<()> {
        let g = self.kin.gravity;
        for (eye, fk) in [&self.kin.left, &self.kin.right].into_iter().enumerate() {
            let mut frozen = fk.frozen(&theta[eye], g)?;
            let [before, after] = m.theta_pm[eye];
            let (a, b) = (frozen.pose(&before)?, frozen.pose(&after)?);
            m.speed_deg_s[eye] = angle_deg(&a.r, &b.r) / (2.0 * SPEED_DT_S);
            let omega = |a: &Matrix3<f64>, b: &Matrix3<f64>, dt: f64| log_so3(&(a.transpose() * b)) / dt;
            m.omega_rad_s[eye] = omega(&a.r, &b.r, 2.0 * SPEED_DT_S);
            let [early, late] = m.theta_wide[eye];
            let (early, late) = (frozen.pose(&early)?.r, frozen.pose(&late)?.r);
            let now = frozen.pose(&theta[eye])?.r;
            // the optical centre (the pose's translation, home frame) differentiated, in the camera's frame
            m.vel_m_s[eye] = now.transpose() * (b.t - a.t) / (2.0 * SPEED_DT_S);
            // in the camera's frame at the instant: R_now^T R_early = exp(-omega dt)
            m.omega_wide_rad_s[eye] = [omega(&early, &now, WIDE_DT_S), omega(&now, &late, WIDE_DT_S)];
            m.band_rot[eye].clear();
            for th in &m.band_theta[eye] {
                let row = frozen.pose(th)?;
                m.band_rot[eye].push(row.r.transpose() * rel[eye].r);
            }
        }
        m.blur_px = m.max_speed_deg_s().to_radians() * m.exposure_ns as f64 * 1e-9 * self.f_out;
        m.gated = m.blur_px > self.motion.gate_blur_px;
        Ok(())
    }

    /// Each eye's encoder latency (s) from its unit model (0 for an FK without one): what time alignment
    /// applies.
    pub fn encoder_latency_s(&self) -> [f64; 2] {
        self.kin.encoder_latency_s()
    }
}

impl Stage for KinematicsStage {
    fn name(&self) -> &'static str {
        "kinematics"
    }

    fn start(&mut self, ctx: &mut StageContext) -> Result<()> {
        let out: RectifiedCamera = ctx.out;
        self.f_out = out.f;
        Ok(())
    }

    fn process(&mut self, w: &mut Work) -> Result<()> {
        let pose = self.kin.solve(&w.theta[0], &w.theta[1])?;
        w.pose = Some(pose);
        self.frame_motion(&w.theta, [&pose.rel_left, &pose.rel_right], &mut w.motion)
    }

    fn failure(&self, e: &RuntimeError) -> &'static str {
        abvs_runtime_core::stage::timing_failure(e).unwrap_or("kinematics or rectification failed")
    }
}

/// An FK error as the runtime's, kept as its source.
fn fk_err<E: std::error::Error + Send + Sync + 'static>(e: E) -> RuntimeError {
    RuntimeError::Fk(Box::new(e))
}

#[cfg(test)]
mod tests {
    use super::*;
    use abvs_eye::Fick;

    #[test]
    fn extrinsic_at_home_is_the_home_calibration_and_moves_with_the_eyes() {
        let home = Pose::new(Fick::from_deg([0.2, -0.1, 0.3]).to_matrix(), Vector3::new(-0.065, 0.001, 0.0));
        let id = Pose::identity();
        let e = moving_extrinsic(&id, &id, &home);
        assert!((e.r - home.r).abs().max() < 1e-15 && (e.t - home.t).norm() < 1e-15);
        // Both eyes yawed together by 10 deg about their own centres: a point fixed in the world keeps its
        // mapping if we express it through the homes.
        let yaw = Pose::new(Fick::from_deg([0.0, 0.0, 10.0]).to_matrix(), Vector3::new(0.001, 0.0, 0.0));
        let yaw_r = Pose::new(Fick::from_deg([1.0, 0.0, 8.0]).to_matrix(), Vector3::zeros());
        let e = moving_extrinsic(&yaw, &yaw_r, &home);
        let p_left_cam = Vector3::new(0.1, -0.2, 0.9);
        let via_home =
            yaw_r.inverse().r * (home.r * (yaw.r * p_left_cam + yaw.t) + home.t - yaw_r.t) + Vector3::zeros();
        let direct = e.r * p_left_cam + e.t;
        assert!((via_home - direct).norm() < 1e-12);
    }

    #[test]
    fn nominal_fk_at_home_is_identity_and_missing_model_is_named() {
        let mut fk = EyeFk::nominal();
        let p = fk.pose(&[0.0; 3], [0.0, 1.0, 0.0]).unwrap();
        assert!((p.r - Matrix3::identity()).abs().max() < 1e-12 && p.t.norm() < 1e-12);
        let e = EyeFk::load(Path::new("/nonexistent/eye0")).err().unwrap().to_string();
        assert!(e.contains("/nonexistent/eye0") && e.contains("no such FK model"), "{e}");
    }
}
