//! What the run computes per unit and model and the figures draw: the test sets and each model's scores per
//! test sample (its own module, so that the figures do not import the run).
use crate::error::{PaperError, Result};
use crate::summary::ModelResult;
use abvs_eye::dataset::Dataset;

/// A unit's test set.
pub(crate) struct TestSet {
    pub(crate) unit: String,
    pub(crate) data: Dataset,
    pub(crate) meas: Vec<[f64; 6]>,
    pub(crate) cmd: Vec<[f64; 3]>,
}

impl TestSet {
    pub(crate) fn new(unit: &str, data: Dataset) -> Result<Self> {
        let cmd = data
            .samples
            .iter()
            .map(|s| s.cmd_deg.ok_or_else(|| PaperError::Data("simulated sample without commanded pose".into())))
            .collect::<Result<_>>()?;
        let meas = data.samples.iter().map(|s| s.pose).collect();
        Ok(TestSet { unit: unit.into(), data, meas, cmd })
    }
}

/// A model's scores plus what the figures need per test sample.
pub(crate) struct Scored {
    pub(crate) result: ModelResult,
    /// Squared error per sample, mean over the six components (MSE_total's summand).
    pub(crate) sq: Vec<f64>,
    pub(crate) mpe: Vec<f64>,
}
