//! Saccades straight on the drive board's link, without the pipeline (`abvs gaze saccade`): both eyes'
//! calibrated IK for each target, the yoked minimum-jerk plan (abvs_fk::gaze), the move executed and measured
//! on the board's stream (abvs_board::saccade).
use std::path::{Path, PathBuf};
use std::time::Duration;

use abvs_board::error::BoardError;
use abvs_board::saccade::BoardSession;
use abvs_camera::{Camera, CameraError, StereoCalibration};
use abvs_eye::Pose;
use abvs_fk::gaze::{Binocular, EyeAim, Torsion, YokedSaccade};
use abvs_fk::ik::CalibratedIk;
use abvs_fk::model::{FkModel, FkState};
use abvs_fk::FkError;
use serde::Serialize;

/// Why a calibration directory could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum HeadCalibrationError {
    /// DIR/stereo.yaml.
    #[error(transparent)]
    Stereo(#[from] CameraError),
    /// DIR/eye0 or DIR/eye1.
    #[error("{}: FK model: {source}", dir.display())]
    Fk {
        /// The calibration directory.
        dir: PathBuf,
        /// The cause.
        #[source]
        source: FkError,
    },
}

/// What points both eyes: the stereo calibration at home and both eyes' FK models, from a calibration
/// directory (DIR/stereo.yaml, DIR/eye0, DIR/eye1).
pub struct HeadCalibration {
    /// T_lH^rH and both cameras.
    pub stereo: StereoCalibration,
    /// Left (eye0) and right (eye1) FK models.
    pub models: [FkModel; 2],
}

impl HeadCalibration {
    /// Loads `dir`.
    pub fn load(dir: &Path) -> Result<HeadCalibration, HeadCalibrationError> {
        let stereo = StereoCalibration::read_yaml(dir.join("stereo.yaml"))?;
        let load = |e: &str| {
            FkModel::load(&dir.join(e)).map_err(|source| HeadCalibrationError::Fk { dir: dir.to_path_buf(), source })
        };
        Ok(HeadCalibration { stereo, models: [load("eye0")?, load("eye1")?] })
    }

    /// Both eyes' calibrated IK with `torsion`.
    pub fn binocular(&self, torsion: Torsion) -> Binocular<'_> {
        Binocular {
            left: CalibratedIk::new(&self.models[0]),
            right: CalibratedIk::new(&self.models[1]),
            left_to_right: Pose::new(self.stereo.rotation, self.stereo.translation_mm),
            torsion,
        }
    }
}

/// Why a saccade could not be run: the board's link or the calibrated IK, each with its own message.
#[derive(Debug, thiserror::Error)]
pub enum SaccadeError {
    /// The board's link (homing, a timeout, the port).
    #[error(transparent)]
    Board(#[from] BoardError),
    /// The calibrated IK refused the target.
    #[error(transparent)]
    Fk(#[from] FkError),
}

/// Where the point an eye aims at lands in its camera `cam` (pixels), seen from the eye's predicted pose;
/// `None` outside the camera model's valid field.
pub fn pixel(cam: &Camera, aim: &EyeAim) -> Option<nalgebra::Vector2<f64>> {
    let p = &aim.ik.pose;
    let r = abvs_eye::Fick::from_deg([p[0], p[1], p[2]]).to_matrix();
    cam.project(&(r.transpose() * (nalgebra::Vector3::from(aim.point_mm) - nalgebra::Vector3::new(p[3], p[4], p[5]))))
}

/// What a saccade aims at.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SaccadeTarget {
    /// Both eyes to this orientation (Fick alpha, beta, gamma, deg).
    Orientation([f64; 3]),
    /// Both eyes fixate this point (m, left home camera frame).
    Point([f64; 3]),
}

/// What one saccade did, measured on the encoder stream.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SaccadeReport {
    /// The target as given (deg or m).
    pub target: [f64; 3],
    /// Per eye: link angles before (deg).
    pub from_deg: [[f64; 3]; 2],
    /// Per eye: link angles planned (deg).
    pub to_deg: [[f64; 3]; 2],
    /// Per eye: target counts (homed).
    pub target_counts: [[i64; 3]; 2],
    /// Largest link travel over both eyes (deg).
    pub travel_deg: f64,
    /// The planned duration (ms).
    pub planned_ms: f64,
    /// From the first moving sample to the first sample at the target (board time), per eye.
    pub measured_ms: [f64; 2],
    /// Largest link speed between consecutive samples (deg/s), per eye.
    pub peak_deg_s: [f64; 2],
    /// Both eyes arrived before the timeout.
    pub arrived: bool,
}

/// Waits until the board has homed both eyes and the links rest; the home counts, and each model's motion
/// history started where the links are.
pub fn start(
    link: &mut BoardSession,
    models: [&FkModel; 2],
    timeout: Duration,
) -> Result<([[i64; 3]; 2], [FkState; 2]), SaccadeError> {
    // Homing decides during the start-up roll; then wait until the links rest.
    let home = link.wait_homed_at_rest(timeout)?;
    let mut st: [FkState; 2] = [models[0].state(), models[1].state()];
    for e in 0..2 {
        let th = link.latest()[e].deg();
        models[e].eval(&mut st[e], &th, [0.0, 1.0, 0.0])?;
    }
    Ok((home, st))
}

/// One yoked saccade to `target` (both eyes move together: the slower eye's duration for both) at
/// `peak_deg_s`, measured on the stream; `st` follows the models' motion history.
pub fn saccade(
    link: &mut BoardSession,
    bino: &Binocular,
    st: &mut [FkState; 2],
    home: [[i64; 3]; 2],
    target: SaccadeTarget,
    peak_deg_s: f64,
    timeout: Duration,
) -> Result<SaccadeReport, SaccadeError> {
    let g = [0.0, 1.0, 0.0];
    let (sol, target) = match target {
        SaccadeTarget::Point(p) => {
            let [l, r] = st;
            let f = bino.fixate_and_move([l, r], p.map(|v| v * 1000.0), [g; 2])?;
            ([f.left.ik.theta_deg, f.right.ik.theta_deg], p)
        }
        SaccadeTarget::Orientation(o) => {
            let mut out = [[0.0; 3]; 2];
            for (e, ik) in [&bino.left, &bino.right].into_iter().enumerate() {
                out[e] = ik.solve_and_move(&mut st[e], o, g)?.theta_deg;
            }
            (out, o)
        }
    };
    let from: [[f64; 3]; 2] = link.latest().map(|t| t.deg());
    let plan = YokedSaccade::plan(from, sol, peak_deg_s);
    let m = link.execute(home, plan.target_counts, plan.duration_us, timeout)?;
    Ok(SaccadeReport {
        target,
        from_deg: from,
        to_deg: plan.to_deg,
        target_counts: plan.target_counts,
        travel_deg: plan.travel_deg(),
        planned_ms: plan.duration_us as f64 * 1e-3,
        measured_ms: m.measured_ms,
        peak_deg_s: m.peak_deg_s,
        arrived: m.arrived,
    })
}
