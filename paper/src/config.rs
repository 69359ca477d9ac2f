//! What to run ([`PaperConfig`]) and on which units (C0..C3, [`paper_unit`]).
use crate::error::{PaperError, Result};
use abvs_eye::UnitModel;
use serde::Serialize;
use std::path::Path;

/// Half-ranges (alpha, beta, gamma, deg) of the paper's restricted-range training.
pub const RESTRICTED_DEG: [f64; 3] = [20.0, 12.0, 20.0];

/// The simulated units C0..C3 (fixtures/units), compiled in so that an installed binary needs
/// no checkout.
pub fn paper_unit(name: &str) -> Result<UnitModel> {
    let (file, text) = match name {
        "C0" => ("c0.toml", include_str!("../../fixtures/units/c0.toml")),
        "C1" => ("c1.toml", include_str!("../../fixtures/units/c1.toml")),
        "C2" => ("c2.toml", include_str!("../../fixtures/units/c2.toml")),
        "C3" => ("c3.toml", include_str!("../../fixtures/units/c3.toml")),
        _ => return Err(PaperError::Config(format!("unknown unit '{name}' (C0, C1, C2, C3)"))),
    };
    Ok(UnitModel::from_toml_str(text, &Path::new("fixtures/units").join(file))?)
}

/// What to run. [`PaperConfig::full`] is the paper's protocol; [`PaperConfig::quick`] shrinks it
/// for tests.
#[derive(Debug, Clone, Serialize)]
pub struct PaperConfig {
    pub seed: u64,
    pub quick: bool,
    /// Grid of the dense session per unit (test and validation sets), deg.
    pub dense_step_deg: f64,
    /// Training grid on C0 (a subset of the dense grid), deg.
    pub train_step_deg: f64,
    /// Fine-tuning grids: n per axis, n^3 commanded poses each.
    pub finetune_n: Vec<usize>,
    /// The n of Table III (one of `finetune_n`).
    pub table_n: usize,
    /// Hybrid fitted from scratch on C0 with n^3 samples, for each n.
    pub hybrid_n: Vec<usize>,
    /// Units fine-tuned for Table III and Fig. 7 (C1, C2, C3).
    pub finetune_units: Vec<String>,
    /// Step of the restricted-range training session, deg.
    pub restricted_step_deg: f64,
    pub max_epochs: usize,
    /// Early stop after this many epochs without validation improvement.
    pub patience: usize,
    /// Keep `<out>/models/` (every trained model directory) instead of deleting it.
    pub keep_models: bool,
}

impl PaperConfig {
    /// The paper's protocol: 1 deg dense grid, 3 deg training grid, 1000 epochs (patience 100),
    /// fine-tuning sizes 64..512 on C1..C3.
    pub fn full(seed: u64) -> Self {
        PaperConfig {
            seed,
            quick: false,
            dense_step_deg: 1.0,
            train_step_deg: 3.0,
            finetune_n: vec![4, 5, 6, 7, 8],
            table_n: 7,
            hybrid_n: vec![4, 7],
            finetune_units: vec!["C1".into(), "C2".into(), "C3".into()],
            restricted_step_deg: 2.0,
            max_epochs: 1000,
            patience: 100,
            keep_models: false,
        }
    }

    /// Everything smaller (2 deg dense / 6 deg training grids, 100 epochs, sizes 64 and 125,
    /// C1 only): the same code paths in well under a minute.
    pub fn quick(seed: u64) -> Self {
        PaperConfig {
            quick: true,
            dense_step_deg: 2.0,
            train_step_deg: 6.0,
            finetune_n: vec![4, 5],
            table_n: 5,
            hybrid_n: vec![4, 5],
            finetune_units: vec!["C1".into()],
            restricted_step_deg: 4.0,
            max_epochs: 100,
            patience: 20,
            ..PaperConfig::full(seed)
        }
    }

    pub(crate) fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(PaperError::Config(m));
        let q = self.train_step_deg / self.dense_step_deg;
        if !(self.dense_step_deg > 0.0 && q >= 2.0 && (q - q.round()).abs() < 1e-9) {
            return bad(format!(
                "training step {} deg must be a multiple (>= 2x) of the dense step {} deg",
                self.train_step_deg, self.dense_step_deg
            ));
        }
        if !self.finetune_n.contains(&self.table_n) {
            return bad(format!("table_n {} is not one of finetune_n {:?}", self.table_n, self.finetune_n));
        }
        if self.finetune_n.iter().chain(&self.hybrid_n).any(|&n| !(3..=12).contains(&n)) {
            return bad("fine-tuning grids need 3..=12 values per axis".into());
        }
        if self.finetune_units.is_empty()
            || self.finetune_units.iter().any(|u| !["C1", "C2", "C3"].contains(&u.as_str()))
        {
            return bad(format!("finetune_units {:?}: one or more of C1, C2, C3", self.finetune_units));
        }
        if !self.restricted_step_deg.is_finite() || self.restricted_step_deg <= 0.0 || self.max_epochs == 0 {
            return bad("restricted step and max_epochs must be > 0".into());
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn units_parse_and_differ() {
        let u: Vec<UnitModel> = ["C0", "C1", "C2", "C3"].iter().map(|n| paper_unit(n).unwrap()).collect();
        assert_eq!(u[0].name, "C0");
        assert_ne!(u[0].to_toml_string(), u[1].to_toml_string());
        assert!(paper_unit("C4").is_err());
    }
}
