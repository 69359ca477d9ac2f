//! Error statistics of a calibrated FK against measured poses, in the paper's layout (Tables II,
//! III): per axis of P the max (99.9th percentile), mean and standard deviation of |error|; the
//! rotational and translational error norms; MSE_total (eq. 11: the mean over samples and the
//! six components of the squared error, deg^2 and mm^2 together); and the mean projection error.
use crate::mpe::Target;
use abvs_eye::pose::rotation_angle_deg;
use abvs_eye::psc::percentile;
use abvs_eye::Pose;
use serde::Serialize;
use std::collections::BTreeMap;

#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
pub struct AxisStats {
    /// 99.9th percentile of |error| (the paper's "max").
    pub max: f64,
    pub mean: f64,
    pub std: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct EvalReport {
    pub n: usize,
    pub rot_deg: BTreeMap<&'static str, AxisStats>,
    pub trans_mm: BTreeMap<&'static str, AxisStats>,
    pub rot_norm_mean_deg: f64,
    pub trans_norm_mean_mm: f64,
    pub mse_total: f64,
    pub mpe_px: f64,
    #[serde(skip)]
    pub per_sample_mpe_px: Vec<f64>,
    #[serde(skip)]
    pub per_sample_rot_deg: Vec<f64>,
}

fn stats(v: &[f64]) -> AxisStats {
    let n = v.len().max(1) as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
    AxisStats { max: percentile(v, 0.999), mean, std: var.sqrt() }
}

/// A model's errors on a dataset's measured poses, against the paper's target (`abvs calib eval`).
pub fn evaluate_model(model: &crate::model::FkModel, data: &abvs_eye::dataset::Dataset) -> crate::Result<EvalReport> {
    let meas: Vec<[f64; 6]> = data.samples.iter().map(|s| s.pose).collect();
    Ok(evaluate(&model.predict_dataset(data)?, &meas, &Target::paper()))
}

/// Compares predictions with measurements sample by sample.
pub fn evaluate(pred: &[[f64; 6]], meas: &[[f64; 6]], target: &Target) -> EvalReport {
    assert_eq!(pred.len(), meas.len());
    let names = ["alpha", "beta", "gamma", "x", "y", "z"];
    let mut abs: Vec<Vec<f64>> = (0..6).map(|_| Vec::with_capacity(pred.len())).collect();
    let mut sq = 0.0;
    let (mut rn, mut tn) = (Vec::new(), 0.0);
    let mut mpe = Vec::with_capacity(pred.len());
    for (p, m) in pred.iter().zip(meas) {
        for k in 0..6 {
            let e = p[k] - m[k];
            abs[k].push(e.abs());
            sq += e * e;
        }
        let (a, b) = (Pose::from_p6(p), Pose::from_p6(m));
        rn.push(rotation_angle_deg(&a.r, &b.r));
        tn += (a.t - b.t).norm();
        mpe.push(target.projection_error_px(&a, &b));
    }
    let n = pred.len();
    let nf = n.max(1) as f64;
    let valid: Vec<f64> = mpe.iter().copied().filter(|v| v.is_finite()).collect();
    EvalReport {
        n,
        rot_deg: (0..3).map(|k| (names[k], stats(&abs[k]))).collect(),
        trans_mm: (3..6).map(|k| (names[k], stats(&abs[k]))).collect(),
        rot_norm_mean_deg: rn.iter().sum::<f64>() / nf,
        trans_norm_mean_mm: tn / nf,
        mse_total: sq / (6.0 * nf),
        mpe_px: valid.iter().sum::<f64>() / valid.len().max(1) as f64,
        per_sample_mpe_px: mpe,
        per_sample_rot_deg: rn,
    }
}

impl EvalReport {
    /// The paper's table layout as plain text.
    pub fn table(&self) -> String {
        let mut s = format!("n = {}\n{:<8}{:>10}{:>10}{:>10}\n", self.n, "axis", "max99.9", "mean", "std");
        for (k, st) in self.rot_deg.iter() {
            s += &format!("{:<8}{:>10.4}{:>10.4}{:>10.4}  deg\n", k, st.max, st.mean, st.std);
        }
        for (k, st) in self.trans_mm.iter() {
            s += &format!("{:<8}{:>10.4}{:>10.4}{:>10.4}  mm\n", k, st.max, st.mean, st.std);
        }
        s += &format!(
            "rotation error norm mean {:.4} deg, translation error norm mean {:.4} mm\nMSE_total {:.5}, MPE {:.3} px\n",
            self.rot_norm_mean_deg, self.trans_norm_mean_mm, self.mse_total, self.mpe_px
        );
        s
    }
}
