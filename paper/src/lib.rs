//! # abvs-paper: the paper's experiments (offline)
//!
//! The paper's experiments on the simulated units C0..C3, regenerated from a seed into one
//! report: `report.md`, `summary.json` and PNG figures.
//!
//! - Table II: on C0, M_h, M1, M2 (and our hybrid) trained on the 3 deg grid, scored on the test
//!   set. As in the paper, one dense session (1 deg grid) is collected; the samples commanded on
//!   the 3 deg grid are the training set and the rest is split 1:10 into validation and test.
//! - Hybrid from scratch on C0 with n^3 samples (the closing note's headline numbers).
//! - Extrapolation: M2 and hybrid trained on alpha, gamma +-20, beta +-12 deg (2 deg step),
//!   scored inside and outside that range.
//! - Table III and Fig. 7: C1..C3 fine-tuned from C0's models with n^3 samples; Fig. 7 splits
//!   the test error by the M4f model's PSC threshold (internal S <= S_init, external S > S_init).
//! - Fig. 8: mean projection error over commanded alpha x gamma (2 deg cells, mean over beta).
//!
//! Every model is written as a model directory and loaded back with [`abvs_calib::model::FkModel::load`] before it
//! is scored, so the numbers are those of the saved files (ONNX networks included). The model
//! directories live in `<out>/models/` and are removed at the end unless
//! [`PaperConfig::keep_models`] is set.
//!
//! Split by concern: [`config`] (what to run, the units), [`run`] (the driver), [`reference`](mod@reference)
//! (the paper's numbers), [`figures`], [`conclusions`], [`report`] (report.md) and [`summary`]
//! (every number, as summary.json). Nothing here is linked into the runtime or the calibration
//! library; the `abvs calib paper` subcommand is a thin shell over [`run_paper`].

pub mod conclusions;
pub mod config;
pub mod error;
pub mod figures;
pub mod reference;
pub mod report;
pub mod run;
mod scored;
pub mod summary;

pub use config::{paper_unit, PaperConfig, RESTRICTED_DEG};
pub use error::{PaperError, Result};
pub use run::run_paper;
pub use summary::*;
