//! The main job's analysis on one unit (`abvs demo`, which prints, plots and writes it): how far the
//! nominal kinematics and the unit's true model are from the measurements of a simulated data collection,
//! where the nominal model is off, and two calibrations scored on a held-out session.
use std::path::Path;
use std::time::Instant;

use abvs_eye::dataset::Dataset;
use abvs_eye::pose::rotation_angle_deg;
use abvs_eye::sim::{simulate_dataset, Commanded, SimSpec};
use abvs_eye::{Pose, UnitModel};
use serde::Serialize;

use crate::methods::{self, FitConfig, Method};
use crate::metrics::{evaluate_model, EvalReport};
use crate::model::{save_model, FkModel};
use crate::Result;

/// Mean errors of predicted poses against measured ones.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PoseErrors {
    /// Mean |error| per axis: alpha, beta, gamma (deg), x, y, z (mm).
    pub mean_abs: [f64; 6],
    /// Mean rotation error (deg).
    pub rot_norm_mean_deg: f64,
    /// Mean translation error norm (mm).
    pub trans_norm_mean_mm: f64,
}

/// Mean |error| per axis and mean rotation / translation error norms of `pred` against `meas`.
pub fn pose_errors(pred: &[[f64; 6]], meas: &[[f64; 6]]) -> PoseErrors {
    let mut m = [0.0; 6];
    let (mut rn, mut tn) = (0.0, 0.0);
    for (p, q) in pred.iter().zip(meas) {
        for k in 0..6 {
            m[k] += (p[k] - q[k]).abs();
        }
        let (a, b) = (Pose::from_p6(p), Pose::from_p6(q));
        rn += rotation_angle_deg(&a.r, &b.r);
        tn += (a.t - b.t).norm();
    }
    let n = pred.len().max(1) as f64;
    PoseErrors { mean_abs: m.map(|x| x / n), rot_norm_mean_deg: rn / n, trans_norm_mean_mm: tn / n }
}

/// The nominal kinematics and a unit's true model against a dataset's measurements.
#[derive(Debug, Clone)]
pub struct KinematicsComparison {
    /// The nominal kinematics' errors.
    pub nominal: PoseErrors,
    /// The unit's true model's errors (the floor: measurement noise).
    pub true_model: PoseErrors,
    /// Where the nominal model is off: (commanded alpha, commanded gamma, rotation error deg) per sample.
    pub nominal_rotation_error: Vec<(f64, f64, f64)>,
}

/// Compares the nominal kinematics and `unit`'s true model with `data`'s measured poses.
pub fn compare_kinematics(unit: &UnitModel, data: &Dataset) -> Result<KinematicsComparison> {
    let meas: Vec<[f64; 6]> = data.samples.iter().map(|s| s.pose).collect();
    let nominal = UnitModel::nominal().compile()?.predict_dataset(data)?;
    let truth = unit.compile()?.predict_dataset(data)?;
    let nominal_rotation_error = data
        .samples
        .iter()
        .zip(&nominal)
        .map(|(s, p)| {
            let c = s.cmd_deg.unwrap_or([s.pose[0], s.pose[1], s.pose[2]]);
            (c[0], c[2], rotation_angle_deg(&Pose::from_p6(p).r, &Pose::from_p6(&s.pose).r))
        })
        .collect();
    Ok(KinematicsComparison {
        nominal: pose_errors(&nominal, &meas),
        true_model: pose_errors(&truth, &meas),
        nominal_rotation_error,
    })
}

/// A separate session to score calibrations on: 2000 random poses of the 1 deg grid, seeded `seed + 1`.
pub fn held_out_session(unit: &UnitModel, seed: u64) -> Result<Dataset> {
    let spec = SimSpec { commanded: Commanded::Step(1.0), random: Some(2000), seed: seed + 1, ..Default::default() };
    Ok(simulate_dataset(unit, &spec, |_, _| {})?.0)
}

/// A calibration fitted, saved and scored on held-out data.
#[derive(Debug, Clone)]
pub struct HeldOutScore {
    /// Its errors on the held-out data.
    pub report: EvalReport,
    /// Fitting, saving, loading and scoring (s).
    pub seconds: f64,
}

/// Fits `method` on `data` (default settings), saves the model to `dir` and scores it, loaded from there,
/// on `test`.
pub fn fit_and_score(method: Method, data: &Dataset, test: &Dataset, dir: &Path) -> Result<HeldOutScore> {
    let t = Instant::now();
    let parts = methods::fit(method, data, None, &FitConfig::default(), &mut |_, _, _, _, _| {})?;
    save_model(dir, &parts)?;
    let report = evaluate_model(&FkModel::load(dir)?, test)?;
    Ok(HeldOutScore { report, seconds: t.elapsed().as_secs_f64() })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_errors_are_means_of_absolute_and_norm_errors() {
        let meas = [[0.0; 6], [0.0; 6]];
        let pred = [[1.0, 0.0, 0.0, 3.0, 4.0, 0.0], [-1.0, 0.0, 0.0, 0.0, 0.0, 0.0]];
        let e = pose_errors(&pred, &meas);
        assert_eq!(e.mean_abs, [1.0, 0.0, 0.0, 1.5, 2.0, 0.0]);
        assert!((e.rot_norm_mean_deg - 1.0).abs() < 1e-9, "{e:?}");
        assert!((e.trans_norm_mean_mm - 2.5).abs() < 1e-12, "{e:?}");
        // no samples: zeros, not NaN
        assert_eq!(pose_errors(&[], &[]).rot_norm_mean_deg, 0.0);
    }

    #[test]
    fn the_true_model_is_closer_than_the_nominal_one() {
        let unit = abvs_eye::sim::draw_unit(3, &abvs_eye::unit::Effect::ALL);
        let spec = SimSpec { commanded: Commanded::Step(15.0), seed: 1, ..Default::default() };
        let (data, _) = simulate_dataset(&unit, &spec, |_, _| {}).unwrap();
        let c = compare_kinematics(&unit, &data).unwrap();
        assert_eq!(c.nominal_rotation_error.len(), data.len());
        assert!(c.true_model.rot_norm_mean_deg < c.nominal.rot_norm_mean_deg, "{c:?}");
    }
}
