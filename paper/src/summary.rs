//! Every number of the report: the rows, points and maps of each table and figure, and
//! [`PaperSummary`] (written as `summary.json`).
use crate::config::PaperConfig;
use abvs_calib::metrics::EvalReport;
use serde::Serialize;

/// The scores of one model on one unit's test set.
#[derive(Debug, Clone, Serialize)]
pub struct ModelResult {
    /// Row label in the report ("M2", "M4f", "M2 of C0 as is", ...).
    pub label: String,
    /// Unit whose test set was scored.
    pub unit: String,
    /// Model directory name under `<out>/models/`.
    pub model: String,
    pub method: abvs_calib::methods::Method,
    /// Unit and size of the data the model was trained / fine-tuned on.
    pub trained_on: String,
    pub train_samples: usize,
    pub train_seconds: f64,
    pub epochs: Vec<usize>,
    /// Euclidean norm of the per-axis mean |error| (the paper's "error norm": its -93 %, -69 %,
    /// -17 % and -3.9 % follow from Table II this way).
    pub rot_norm_of_means_deg: f64,
    pub trans_norm_of_means_mm: f64,
    pub eval: EvalReport,
}

/// Fig. 7: one model at one fine-tuning size, its test error split by the M4f model's PSC
/// threshold.
#[derive(Debug, Clone, Serialize)]
pub struct Fig7Point {
    pub unit: String,
    pub label: String,
    pub n_per_axis: usize,
    pub samples: usize,
    pub s_init: f64,
    /// Fraction of the test set with S <= s_init.
    pub internal_fraction: f64,
    pub mse_total: f64,
    pub mse_internal: f64,
    pub mse_external: f64,
}

/// Extrapolation experiment: MSE_total inside the restricted range, outside it, whole test set.
#[derive(Debug, Clone, Serialize)]
pub struct ExtrapRow {
    pub label: String,
    pub trained_on: String,
    pub train_samples: usize,
    pub mse_inside: f64,
    pub mse_outside: f64,
    pub mse_whole: f64,
    pub outside_over_inside: f64,
    /// The paper's (inside, outside, whole) for the same kind of model, if it reports one.
    pub paper: Option<[f64; 3]>,
}

/// Fig. 8: one MPE map.
#[derive(Debug, Clone, Serialize)]
pub struct Fig8Map {
    pub figure: String,
    pub unit: String,
    pub label: String,
    pub file: String,
    pub mean_mpe_px: f64,
    /// Mean over cells with max(|alpha|, |gamma|) <= 10 deg, and > 20 deg.
    pub centre_mpe_px: f64,
    pub outer_mpe_px: f64,
    pub colour_range_px: (f64, f64),
}

#[derive(Debug, Clone, Serialize)]
pub struct DataInfo {
    pub unit: String,
    pub session: String,
    pub commanded: usize,
    pub written: usize,
    pub max_dev_rot_deg: f64,
    pub max_dev_trans_mm: f64,
}

/// One of the paper's conclusions and whether it holds on our units.
#[derive(Debug, Clone, Serialize)]
pub struct Conclusion {
    pub claim: String,
    pub paper: String,
    pub ours: String,
    /// "holds", "partly holds" or "does not hold".
    pub verdict: String,
}

/// Every number of the report (also written as `summary.json`).
#[derive(Debug, Clone, Serialize)]
pub struct PaperSummary {
    pub config: PaperConfig,
    pub seconds: f64,
    pub stages: Vec<(String, f64)>,
    pub data: Vec<DataInfo>,
    /// C0 split of the dense session: training (train grid), validation, test.
    pub c0_split: [usize; 3],
    /// Per unit, the MSE_total of a perfect model: its measurement noise alone,
    /// (sigma_rot^2 + sigma_trans^2) / 2 (Fick-angle errors taken equal to the rotation noise).
    pub noise_floor_mse: Vec<(String, f64)>,
    pub table2: Vec<ModelResult>,
    pub hybrid_few: Vec<ModelResult>,
    pub table3: Vec<ModelResult>,
    pub fig7: Vec<Fig7Point>,
    pub extrapolation: Vec<ExtrapRow>,
    pub fig8: Vec<Fig8Map>,
    /// The closing note's numbers, by name.
    pub headline: std::collections::BTreeMap<String, f64>,
    pub conclusions: Vec<Conclusion>,
    pub files: Vec<String>,
}
