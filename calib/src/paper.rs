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
//! Every model is written as a model directory and loaded back with [`FkModel::load`] before it
//! is scored, so the numbers are those of the saved files (ONNX networks included). The model
//! directories live in `<out>/models/` and are removed at the end unless
//! [`PaperConfig::keep_models`] is set.
use crate::error::{CalibError, Result};
use crate::methods::{finetune, fit, validation_mask, FitConfig, Method};
use crate::metrics::{evaluate, EvalReport};
use crate::model::{save_model, FkModel, ModelParts};
use crate::mpe::Target;
use abvs_eye::dataset::{Dataset, Sample};
use abvs_eye::sim::{simulate_dataset, Commanded, SimSpec};
use abvs_eye::{UnitModel, WORKSPACE_DEG};
use abvs_plot::{Heatmap, Series, SeriesStyle, XyPlot};
use serde::Serialize;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Half-ranges (alpha, beta, gamma, deg) of the paper's restricted-range training.
pub const RESTRICTED_DEG: [f64; 3] = [20.0, 12.0, 20.0];
/// Fig. 8 cell size (deg).
const CELL_DEG: f64 = 2.0;
/// Fig. 8 regions for "grows from the centre outwards": max(|alpha|, |gamma|) of the cell centre.
const CENTRE_DEG: f64 = 10.0;
const OUTER_DEG: f64 = 20.0;

/// The simulated units C0..C3 (fixtures/units), compiled in so that an installed binary needs
/// no checkout.
pub fn paper_unit(name: &str) -> Result<UnitModel> {
    let (file, text) = match name {
        "C0" => ("c0.toml", include_str!("../../fixtures/units/c0.toml")),
        "C1" => ("c1.toml", include_str!("../../fixtures/units/c1.toml")),
        "C2" => ("c2.toml", include_str!("../../fixtures/units/c2.toml")),
        "C3" => ("c3.toml", include_str!("../../fixtures/units/c3.toml")),
        _ => return Err(CalibError::Invalid(format!("unknown unit '{name}' (C0, C1, C2, C3)"))),
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

    fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(CalibError::Invalid(m));
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

/// The scores of one model on one unit's test set.
#[derive(Debug, Clone, Serialize)]
pub struct ModelResult {
    /// Row label in the report ("M2", "M4f", "M2 of C0 as is", ...).
    pub label: String,
    /// Unit whose test set was scored.
    pub unit: String,
    /// Model directory name under `<out>/models/`.
    pub model: String,
    pub method: String,
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

// ---- the paper's numbers (shared/reference/paper.md) ----------------------------------------

/// Table II, mean |error|: alpha, beta, gamma (deg), x, y, z (mm).
const PAPER_T2: [(&str, [f64; 6]); 3] = [
    ("M_h", [2.053, 0.443, 2.059, 1.714, 0.960, 1.047]),
    ("M1", [0.138, 0.152, 0.136, 0.412, 0.375, 0.428]),
    ("M2", [0.116, 0.122, 0.115, 0.398, 0.364, 0.405]),
];
/// 99.9th percentiles of |error| for M2 (Table II).
const PAPER_M2_MAX: [f64; 6] = [0.65, 1.01, 0.61, 3.4, 4.5, 2.5];
/// Table III, mean |error| alpha/beta/gamma (deg): M_h, M1 of C0 as is, M1f, M2f, M4f.
const PAPER_T3: [(&str, [[f64; 3]; 5]); 3] = [
    ("C1", [[2.10, 0.60, 1.06], [0.36, 0.43, 0.55], [0.25, 0.25, 0.25], [0.21, 0.23, 0.24], [0.21, 0.21, 0.24]]),
    ("C2", [[2.26, 0.47, 1.96], [0.97, 0.41, 0.26], [0.22, 0.21, 0.22], [0.20, 0.16, 0.21], [0.19, 0.15, 0.20]]),
    ("C3", [[2.12, 0.42, 1.99], [0.53, 0.31, 0.33], [0.22, 0.19, 0.22], [0.19, 0.15, 0.21], [0.18, 0.14, 0.20]]),
];
const PAPER_T3_LABELS: [&str; 5] = ["M_h", "M1 of C0 as is", "M1f", "M2f", "M4f"];
/// Table III, M4f translation mean |error| x, y, z (mm).
const PAPER_T3_M4F_TRANS: [(&str, [f64; 3]); 3] =
    [("C1", [0.42, 0.39, 0.58]), ("C2", [0.28, 0.25, 0.21]), ("C3", [0.25, 0.24, 0.20])];
/// Restricted training, MSE_total (inside, outside, whole test set).
const PAPER_M2_RESTRICTED: [f64; 3] = [0.079, 1.904, 0.528];
const PAPER_M2_FULL: [f64; 3] = [0.088, 0.222, 0.180];

/// Table III row order.
const T3_ORDER: [&str; 7] = ["M_h", "M1 of C0 as is", "M2 of C0 as is", "M1f", "M2f", "M4f", "hybrid"];

// ---- running ----------------------------------------------------------------------------------

/// A trained model, loaded back from its directory.
struct Trained {
    name: String,
    model: FkModel,
    trained_on: String,
    samples: usize,
    seconds: f64,
    epochs: Vec<usize>,
}

/// A unit's test set.
struct TestSet {
    unit: String,
    data: Dataset,
    meas: Vec<[f64; 6]>,
    cmd: Vec<[f64; 3]>,
}

impl TestSet {
    fn new(unit: &str, data: Dataset) -> Result<Self> {
        let cmd = data
            .samples
            .iter()
            .map(|s| s.cmd_deg.ok_or_else(|| CalibError::Data("simulated sample without commanded pose".into())))
            .collect::<Result<_>>()?;
        let meas = data.samples.iter().map(|s| s.pose).collect();
        Ok(TestSet { unit: unit.into(), data, meas, cmd })
    }
}

/// A model's scores plus what the figures need per test sample.
struct Scored {
    result: ModelResult,
    /// Squared error per sample, mean over the six components (MSE_total's summand).
    sq: Vec<f64>,
    mpe: Vec<f64>,
}

struct Ctx<'a> {
    cfg: &'a PaperConfig,
    models: PathBuf,
    t0: Instant,
    stage_t0: Instant,
    stages: Vec<(String, f64)>,
    progress: &'a mut dyn FnMut(&str),
    fit_cfg: FitConfig,
    target: Target,
    data: Vec<DataInfo>,
}

fn quiet(_: &str, _: usize, _: usize, _: f64, _: f64) {}

impl Ctx<'_> {
    fn log(&mut self, msg: &str) {
        let line = format!("[{:7.1} s] {msg}", self.t0.elapsed().as_secs_f64());
        (self.progress)(&line);
    }

    fn stage(&mut self, name: &str) {
        self.end_stage();
        self.stages.push((name.to_string(), f64::NAN));
        self.stage_t0 = Instant::now();
        self.log(&format!("== {name}"));
    }

    fn end_stage(&mut self) {
        if let Some(last) = self.stages.last_mut() {
            if last.1.is_nan() {
                last.1 = self.stage_t0.elapsed().as_secs_f64();
            }
        }
    }

    fn simulate(&mut self, unit_name: &str, unit: &UnitModel, session: &str, spec: SimSpec) -> Result<Dataset> {
        let (data, st) = simulate_dataset(unit, &spec, |_, _| {})?;
        self.data.push(DataInfo {
            unit: unit_name.into(),
            session: session.into(),
            commanded: st.commanded,
            written: st.written,
            max_dev_rot_deg: st.max_dev_rot_deg,
            max_dev_trans_mm: st.max_dev_trans_mm,
        });
        Ok(data)
    }

    /// Saves the model and loads it back: what is scored is what was written.
    fn keep(
        &mut self,
        name: &str,
        parts: ModelParts,
        trained_on: String,
        samples: usize,
        t: Instant,
    ) -> Result<Trained> {
        let dir = self.models.join(name);
        save_model(&dir, &parts)?;
        let model = FkModel::load(&dir)?;
        Ok(Trained {
            name: name.into(),
            model,
            trained_on,
            samples,
            seconds: t.elapsed().as_secs_f64(),
            epochs: parts.manifest.training.epochs.clone(),
        })
    }

    fn fit(&mut self, name: &str, method: Method, data: &Dataset, val: Option<&Dataset>, on: &str) -> Result<Trained> {
        let t = Instant::now();
        let parts = fit(method, data, val, &self.fit_cfg, &mut quiet)?;
        self.keep(name, parts, on.into(), data.len(), t)
    }

    fn finetune(&mut self, name: &str, method: Method, base: &FkModel, data: &Dataset, on: &str) -> Result<Trained> {
        let t = Instant::now();
        // No validation set beyond the fine-tuning samples (10 % held out): with n^3 samples
        // collected, that is all a user has.
        let parts = finetune(method, base, data, None, &self.fit_cfg, &mut quiet)?;
        self.keep(name, parts, on.into(), data.len(), t)
    }

    fn score(&mut self, label: &str, t: &Trained, test: &TestSet) -> Result<Scored> {
        let pred = t.model.predict_dataset(&test.data)?;
        let mut eval = evaluate(&pred, &test.meas, &self.target);
        let sq = pred
            .iter()
            .zip(&test.meas)
            .map(|(p, m)| (0..6).map(|k| (p[k] - m[k]).powi(2)).sum::<f64>() / 6.0)
            .collect();
        let mpe = std::mem::take(&mut eval.per_sample_mpe_px);
        eval.per_sample_rot_deg = Vec::new();
        let norm = |m: &std::collections::BTreeMap<&'static str, crate::metrics::AxisStats>| {
            m.values().map(|s| s.mean * s.mean).sum::<f64>().sqrt()
        };
        let result = ModelResult {
            label: label.into(),
            unit: test.unit.clone(),
            model: t.name.clone(),
            method: t.model.method().into(),
            trained_on: t.trained_on.clone(),
            train_samples: t.samples,
            train_seconds: t.seconds,
            epochs: t.epochs.clone(),
            rot_norm_of_means_deg: norm(&eval.rot_deg),
            trans_norm_of_means_mm: norm(&eval.trans_mm),
            eval,
        };
        self.log(&format!(
            "{} {label:<16} ({}, {:.1} s): rot {:.4} deg, trans {:.4} mm, MSE_total {:.5}, MPE {:.2} px",
            test.unit,
            t.trained_on,
            t.seconds,
            result.rot_norm_of_means_deg,
            result.trans_norm_of_means_mm,
            result.eval.mse_total,
            result.eval.mpe_px
        ));
        Ok(Scored { result, sq, mpe })
    }
}

/// Seed of one simulated session: the run's seed mixed with a fixed tag (FNV-1a).
fn sub_seed(seed: u64, tag: &str) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64 ^ seed.wrapping_mul(0x9e37_79b9_7f4a_7c15);
    for b in tag.bytes() {
        h = (h ^ b as u64).wrapping_mul(0x0100_0000_01b3);
    }
    h
}

fn pick(d: &Dataset, keep: impl Fn(usize, &Sample) -> bool) -> Dataset {
    Dataset {
        samples: d.samples.iter().enumerate().filter(|(i, s)| keep(*i, s)).map(|(_, s)| s.clone()).collect(),
        extra_columns: d.extra_columns.clone(),
    }
}

fn cmd_of(s: &Sample) -> [f64; 3] {
    s.cmd_deg.unwrap_or([f64::NAN; 3])
}

/// Whether a commanded pose lies on the training grid (the simulator's grids start at -range).
fn on_grid(c: &[f64; 3], step: f64) -> bool {
    (0..3).all(|k| {
        let q = (c[k] + WORKSPACE_DEG[k]) / step;
        (q - q.round()).abs() < 1e-6
    })
}

fn inside_restricted(c: &[f64; 3]) -> bool {
    (0..3).all(|k| c[k].abs() <= RESTRICTED_DEG[k] + 1e-9)
}

/// The paper's split of a dense session: training-grid poses; the rest 1:10 validation : test.
fn split_dense(dense: &Dataset, cfg: &PaperConfig) -> (Dataset, Dataset, Dataset) {
    let train = pick(dense, |_, s| on_grid(&cmd_of(s), cfg.train_step_deg));
    let rest = pick(dense, |_, s| !on_grid(&cmd_of(s), cfg.train_step_deg));
    let is_val = validation_mask(rest.len(), 1.0 / 11.0, cfg.seed);
    let val = pick(&rest, |i, _| is_val[i]);
    let test = pick(&rest, |i, _| !is_val[i]);
    (train, val, test)
}

fn mean_where(v: &[f64], mask: impl Fn(usize) -> bool) -> f64 {
    let (s, n) = v
        .iter()
        .enumerate()
        .filter(|(i, x)| mask(*i) && x.is_finite())
        .fold((0.0, 0usize), |(s, n), (_, x)| (s + x, n + 1));
    if n == 0 {
        f64::NAN
    } else {
        s / n as f64
    }
}

fn dense_spec(cfg: &PaperConfig, tag: &str) -> SimSpec {
    SimSpec { commanded: Commanded::Step(cfg.dense_step_deg), seed: sub_seed(cfg.seed, tag), ..Default::default() }
}

/// An n^3 fine-tuning grid. No dropout: whoever collects a few hundred poses re-takes the
/// failed ones, and the sizes stay the paper's 64..512.
fn grid_spec(cfg: &PaperConfig, n: usize, tag: &str) -> SimSpec {
    SimSpec { commanded: Commanded::PerAxis(n), seed: sub_seed(cfg.seed, tag), dropout: 0.0, ..Default::default() }
}

fn plot_err(e: abvs_plot::PlotError) -> CalibError {
    // CalibError has no plot variant; every plot error is about the PNG it names.
    CalibError::Io { path: PathBuf::from("(plot)"), source: std::io::Error::other(e) }
}

/// Runs every experiment and writes `report.md`, `summary.json` and the PNGs into `out`.
/// `progress` gets one line per stage and per trained model.
pub fn run_paper(cfg: &PaperConfig, out: &Path, progress: &mut dyn FnMut(&str)) -> Result<PaperSummary> {
    cfg.validate()?;
    std::fs::create_dir_all(out).map_err(|e| CalibError::io(out, e))?;
    let models = out.join("models");
    let fit_cfg =
        FitConfig { max_epochs: cfg.max_epochs, patience: cfg.patience, seed: cfg.seed, ..FitConfig::default() };
    let mut cx = Ctx {
        cfg,
        models: models.clone(),
        t0: Instant::now(),
        stage_t0: Instant::now(),
        stages: vec![],
        progress,
        fit_cfg,
        target: Target::paper(),
        data: vec![],
    };
    let r = run_all(&mut cx, out);
    if !cfg.keep_models {
        // The report directory keeps only report.md, summary.json and the figures.
        let _ = std::fs::remove_dir_all(&models);
    }
    r
}

fn run_all(cx: &mut Ctx, out: &Path) -> Result<PaperSummary> {
    let cfg = cx.cfg;
    let mut files = vec![];

    // ---- C0: data, Table II ----
    cx.stage("C0: simulate the dense session, split training / validation / test");
    let c0 = paper_unit("C0")?;
    let dense =
        cx.simulate("C0", &c0, &format!("dense {} deg grid", cfg.dense_step_deg), dense_spec(cfg, "C0/dense"))?;
    let (train, val, test) = split_dense(&dense, cfg);
    drop(dense);
    let c0_split = [train.len(), val.len(), test.len()];
    cx.log(&format!(
        "C0: {} training ({} deg grid), {} validation, {} test samples",
        train.len(),
        cfg.train_step_deg,
        val.len(),
        test.len()
    ));
    let test0 = TestSet::new("C0", test)?;
    let on = format!("C0 {} deg grid", cfg.train_step_deg);

    cx.stage("Table II: M_h, M1, M2, hybrid on C0");
    let mh = cx.fit("c0_mh", Method::Mh, &train, Some(&val), &on)?;
    let s_mh = cx.score("M_h", &mh, &test0)?;
    let m1 = cx.fit("c0_m1", Method::M1, &train, Some(&val), &on)?;
    let s_m1 = cx.score("M1", &m1, &test0)?;
    let m2 = cx.fit("c0_m2", Method::M2, &train, Some(&val), &on)?;
    let s_m2 = cx.score("M2", &m2, &test0)?;
    let hy = cx.fit("c0_hybrid", Method::Hybrid, &train, Some(&val), &on)?;
    let s_hy = cx.score("hybrid", &hy, &test0)?;

    // ---- hybrid from few samples ----
    cx.stage("C0: hybrid from scratch on n^3 grids");
    let mut hybrid_few = vec![];
    for &n in &cfg.hybrid_n {
        let d = cx.simulate("C0", &c0, &format!("{n}^3 grid"), grid_spec(cfg, n, &format!("C0/grid{n}")))?;
        let t = cx.fit(&format!("c0_hybrid_n{n}"), Method::Hybrid, &d, None, &format!("C0 {n}^3 grid"))?;
        hybrid_few.push(cx.score(&format!("hybrid ({} samples)", n * n * n), &t, &test0)?.result);
    }

    // ---- extrapolation ----
    cx.stage("Extrapolation: M2 and hybrid trained on the +-20 deg range");
    let spec = SimSpec {
        commanded: Commanded::Step(cfg.restricted_step_deg),
        range_deg: RESTRICTED_DEG,
        seed: sub_seed(cfg.seed, "C0/restricted"),
        ..Default::default()
    };
    let restricted =
        cx.simulate("C0", &c0, &format!("restricted +-20/12/20, {} deg grid", cfg.restricted_step_deg), spec)?;
    // A restricted collection has no poses outside its range to validate on either.
    let val_in = pick(&val, |_, s| inside_restricted(&cmd_of(s)));
    let on_r = format!("C0 +-20/12/20 deg, {} deg grid", cfg.restricted_step_deg);
    let m2r = cx.fit("c0_m2_restricted", Method::M2, &restricted, Some(&val_in), &on_r)?;
    let s_m2r = cx.score("M2'", &m2r, &test0)?;
    let hyr = cx.fit("c0_hybrid_restricted", Method::Hybrid, &restricted, Some(&val_in), &on_r)?;
    let s_hyr = cx.score("hybrid'", &hyr, &test0)?;
    let inside: Vec<bool> = test0.cmd.iter().map(inside_restricted).collect();
    let extrap_row = |label: &str, s: &Scored, paper: Option<[f64; 3]>| {
        let (i, o) = (mean_where(&s.sq, |k| inside[k]), mean_where(&s.sq, |k| !inside[k]));
        ExtrapRow {
            label: label.into(),
            trained_on: s.result.trained_on.clone(),
            train_samples: s.result.train_samples,
            mse_inside: i,
            mse_outside: o,
            mse_whole: s.result.eval.mse_total,
            outside_over_inside: o / i,
            paper,
        }
    };
    let extrapolation = vec![
        extrap_row("M2 (full range)", &s_m2, Some(PAPER_M2_FULL)),
        extrap_row("M2' (restricted)", &s_m2r, Some(PAPER_M2_RESTRICTED)),
        extrap_row("hybrid (full range)", &s_hy, None),
        extrap_row("hybrid' (restricted)", &s_hyr, None),
    ];
    drop((s_m2r, s_hyr, m2r, hyr));

    // ---- fine-tuning: Table III, Fig. 7 ----
    let mut table3: Vec<ModelResult> = vec![];
    let mut fig7: Vec<Fig7Point> = vec![];
    let mut fig8_c1: Vec<(String, Scored)> = vec![];
    let mut fig8_c1_test: Option<TestSet> = None;
    for uname in &cfg.finetune_units {
        cx.stage(&format!("{uname}: fine-tuning C0's models (Table III, Fig. 7)"));
        let unit = paper_unit(uname)?;
        let lower = uname.to_lowercase();
        let dense = cx.simulate(
            uname,
            &unit,
            &format!("dense {} deg grid", cfg.dense_step_deg),
            dense_spec(cfg, &format!("{uname}/dense")),
        )?;
        let (_, _, test) = split_dense(&dense, cfg);
        drop(dense);
        let test_u = TestSet::new(uname, test)?;
        // S depends only on the nominal kinematics: one pass serves every model's split.
        let s_test: Vec<f64> = {
            let mut st = m2.model.state();
            test_u.data.samples.iter().map(|s| m2.model.psc(&mut st, &s.theta_deg)).collect::<Result<_>>()?
        };
        let first = fig8_c1_test.is_none();
        let mut rows = vec![];
        let m1_as_is = cx.score("M1 of C0 as is", &m1, &test_u)?;
        rows.push(m1_as_is.result);
        let m2_as_is = cx.score("M2 of C0 as is", &m2, &test_u)?;
        rows.push(m2_as_is.result.clone());
        if first {
            fig8_c1.push(("M2 of C0 as is".into(), m2_as_is));
        }
        for &n in &cfg.finetune_n {
            let ns = n * n * n;
            let ft =
                cx.simulate(uname, &unit, &format!("{n}^3 grid"), grid_spec(cfg, n, &format!("{uname}/grid{n}")))?;
            let on = format!("{uname} {n}^3 grid");
            let mut scored = vec![];
            for (label, method, base) in [
                ("M4f", Method::M4f, &m2.model),
                ("M2f", Method::M2f, &m2.model),
                ("hybrid", Method::Hybrid, &hy.model),
            ] {
                let t = cx.finetune(&format!("{lower}_{}_n{n}", method.name()), method, base, &ft, &on)?;
                let s_init = t.model.manifest.psc.map(|p| p.s_init);
                scored.push((label, cx.score(label, &t, &test_u)?, s_init));
            }
            let s_init = scored[0].2.ok_or_else(|| CalibError::Data("m4f model without PSC split".into()))?;
            let internal: Vec<bool> = s_test.iter().map(|&s| s <= s_init).collect();
            let frac = internal.iter().filter(|&&b| b).count() as f64 / internal.len().max(1) as f64;
            for (label, s, _) in &scored {
                fig7.push(Fig7Point {
                    unit: uname.clone(),
                    label: label.to_string(),
                    n_per_axis: n,
                    samples: s.result.train_samples,
                    s_init,
                    internal_fraction: frac,
                    mse_total: s.result.eval.mse_total,
                    mse_internal: mean_where(&s.sq, |k| internal[k]),
                    mse_external: mean_where(&s.sq, |k| !internal[k]),
                });
            }
            if n == cfg.table_n {
                let t = cx.fit(&format!("{lower}_mh_n{n}"), Method::Mh, &ft, None, &on)?;
                rows.push(cx.score("M_h", &t, &test_u)?.result);
                let t = cx.finetune(&format!("{lower}_m1f_n{n}"), Method::M1f, &m1.model, &ft, &on)?;
                rows.push(cx.score("M1f", &t, &test_u)?.result);
                for (label, s, _) in scored {
                    rows.push(s.result.clone());
                    if first && label != "M2f" {
                        fig8_c1.push((format!("{label} ({ns})"), s));
                    }
                }
            }
        }
        rows.sort_by_key(|r| T3_ORDER.iter().position(|l| *l == r.label).unwrap_or(usize::MAX));
        table3.extend(rows);
        if first {
            fig8_c1_test = Some(test_u);
        }
    }

    // ---- figures ----
    cx.stage("Figures");
    let fig7_files = plot_fig7(out, &fig7, cfg)?;
    files.extend(fig7_files);
    let mut fig8 = vec![];
    let c0_maps: Vec<(String, &Scored)> =
        vec![("M_h".into(), &s_mh), ("M1".into(), &s_m1), ("M2".into(), &s_m2), ("hybrid".into(), &s_hy)];
    fig8.extend(plot_fig8(out, "fig8_c0", "C0", &test0, &c0_maps)?);
    if let Some(t) = &fig8_c1_test {
        let maps: Vec<(String, &Scored)> = fig8_c1.iter().map(|(l, s)| (l.clone(), s)).collect();
        fig8.extend(plot_fig8(out, &format!("fig8_{}", t.unit.to_lowercase()), &t.unit, t, &maps)?);
    }
    files.extend(fig8.iter().map(|m| m.file.clone()));

    // ---- summary, report ----
    cx.stage("Report");
    let table2 = vec![s_mh.result.clone(), s_m1.result.clone(), s_m2.result.clone(), s_hy.result.clone()];
    let mut summary = PaperSummary {
        config: cfg.clone(),
        seconds: 0.0,
        stages: vec![],
        data: std::mem::take(&mut cx.data),
        c0_split,
        noise_floor_mse: std::iter::once("C0")
            .chain(cfg.finetune_units.iter().map(|u| u.as_str()))
            .map(|u| {
                let n = paper_unit(u).map(|x| x.effects.measurement_noise).unwrap_or_default();
                (u.to_string(), (n.rot_deg.powi(2) + n.trans_mm.powi(2)) / 2.0)
            })
            .collect(),
        table2,
        hybrid_few,
        table3,
        fig7,
        extrapolation,
        fig8,
        headline: Default::default(),
        conclusions: vec![],
        files: vec![],
    };
    summary.headline = headline(&summary);
    summary.conclusions = conclusions(&summary);
    files.push("report.md".into());
    files.push("summary.json".into());
    summary.files = files;
    cx.end_stage();
    summary.stages = cx.stages.clone();
    summary.seconds = cx.t0.elapsed().as_secs_f64();
    let p = out.join("summary.json");
    let json = serde_json::to_string_pretty(&summary).expect("summary serialises");
    std::fs::write(&p, json).map_err(|e| CalibError::io(&p, e))?;
    let p = out.join("report.md");
    std::fs::write(&p, report_md(&summary)).map_err(|e| CalibError::io(&p, e))?;
    cx.log(&format!("wrote {} ({:.0} s in all)", out.display(), summary.seconds));
    Ok(summary)
}

// ---- figures ----------------------------------------------------------------------------------

fn plot_fig7(out: &Path, pts: &[Fig7Point], cfg: &PaperConfig) -> Result<Vec<String>> {
    let mut files = vec![];
    for unit in &cfg.finetune_units {
        let mut labels = vec![];
        let mut series_pts = vec![];
        for method in ["M4f", "M2f", "hybrid"] {
            for (region, get) in [("internal", 0), ("external", 1)] {
                let p: Vec<(f64, f64)> = pts
                    .iter()
                    .filter(|p| &p.unit == unit && p.label == method)
                    .map(|p| (p.samples as f64, if get == 0 { p.mse_internal } else { p.mse_external }))
                    .collect();
                labels.push(format!("{method}, {region}"));
                series_pts.push(p);
            }
        }
        let series = labels
            .iter()
            .zip(series_pts)
            .map(|(l, points)| Series { label: l.as_str(), points, style: SeriesStyle::LinePoints })
            .collect();
        let title = format!("Fig. 7 ({unit}): test MSE_total vs fine-tuning size");
        let file = format!("fig7_{}.png", unit.to_lowercase());
        let plot = XyPlot {
            title: &title,
            x_label: "fine-tuning samples",
            y_label: "MSE_total (deg^2, mm^2)",
            series,
            log_y: true,
        };
        abvs_plot::xy_plot(&out.join(&file), &plot).map_err(plot_err)?;
        files.push(file);
    }
    Ok(files)
}

/// Mean of per-sample values binned over commanded alpha (x) x gamma (y), `CELL_DEG` cells
/// spanning the workspace (the edge poses at +-30 join the outermost cells).
fn cells(test: &TestSet, v: &[f64]) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let (ra, rg) = (WORKSPACE_DEG[0], WORKSPACE_DEG[2]);
    let (na, ng) = ((2.0 * ra / CELL_DEG).round() as usize, (2.0 * rg / CELL_DEG).round() as usize);
    let idx = |c: f64, r: f64, n: usize| (((c + r) / CELL_DEG).floor().max(0.0) as usize).min(n - 1);
    let mut acc = vec![(0.0, 0usize); na * ng];
    for (c, &x) in test.cmd.iter().zip(v) {
        if x.is_finite() && c[0].is_finite() && c[2].is_finite() {
            let cell = &mut acc[idx(c[2], rg, ng) * na + idx(c[0], ra, na)];
            cell.0 += x;
            cell.1 += 1;
        }
    }
    let centres = |r: f64, n: usize| (0..n).map(|k| -r + CELL_DEG * (k as f64 + 0.5)).collect();
    let values = acc.iter().map(|&(s, n)| if n == 0 { f64::NAN } else { s / n as f64 }).collect();
    (centres(ra, na), centres(rg, ng), values)
}

fn plot_fig8(out: &Path, stem: &str, unit: &str, test: &TestSet, maps: &[(String, &Scored)]) -> Result<Vec<Fig8Map>> {
    let grids: Vec<_> = maps.iter().map(|(_, s)| cells(test, &s.mpe)).collect();
    // One colour scale per figure so that the maps compare.
    let hi = grids.iter().flat_map(|g| g.2.iter()).copied().filter(|v| v.is_finite()).fold(0.0, f64::max);
    let range = (0.0, hi.max(1e-6));
    let mut res = vec![];
    for ((label, s), (x, y, values)) in maps.iter().zip(grids) {
        let slug: String =
            label.chars().map(|c| if c.is_ascii_alphanumeric() { c.to_ascii_lowercase() } else { '_' }).collect();
        let slug = slug.split('_').filter(|p| !p.is_empty()).collect::<Vec<_>>().join("_");
        let file = format!("{stem}_{slug}.png");
        let title = format!("{unit}, {label}: MPE (mean over beta)");
        let region = |keep: &dyn Fn(f64) -> bool| {
            let mut v = vec![];
            for (iy, gy) in y.iter().enumerate() {
                for (ix, gx) in x.iter().enumerate() {
                    let c = values[iy * x.len() + ix];
                    if c.is_finite() && keep(gx.abs().max(gy.abs())) {
                        v.push(c);
                    }
                }
            }
            v.iter().sum::<f64>() / v.len().max(1) as f64
        };
        let (centre, outer) = (region(&|m| m <= CENTRE_DEG), region(&|m| m > OUTER_DEG));
        let h = Heatmap {
            title: &title,
            x_label: "commanded alpha (deg)",
            y_label: "commanded gamma (deg)",
            colorbar_label: "MPE (px)",
            x,
            y,
            values,
            range: Some(range),
        };
        abvs_plot::heatmap(&out.join(&file), &h).map_err(plot_err)?;
        res.push(Fig8Map {
            figure: stem.into(),
            unit: unit.into(),
            label: label.clone(),
            file,
            mean_mpe_px: s.result.eval.mpe_px,
            centre_mpe_px: centre,
            outer_mpe_px: outer,
            colour_range_px: range,
        });
    }
    Ok(res)
}

// ---- headline numbers and conclusions -----------------------------------------------------------

fn find<'a>(rows: &'a [ModelResult], unit: &str, label: &str) -> Option<&'a ModelResult> {
    rows.iter().find(|r| r.unit == unit && r.label == label)
}

fn reduction_pct(new: f64, old: f64) -> f64 {
    100.0 * (1.0 - new / old)
}

fn headline(s: &PaperSummary) -> std::collections::BTreeMap<String, f64> {
    let mut h = std::collections::BTreeMap::new();
    let t2 = |l: &str| find(&s.table2, "C0", l);
    if let (Some(mh), Some(m1), Some(m2), Some(hy)) = (t2("M_h"), t2("M1"), t2("M2"), t2("hybrid")) {
        h.insert(
            "m2_vs_m1_rot_reduction_pct".into(),
            reduction_pct(m2.rot_norm_of_means_deg, m1.rot_norm_of_means_deg),
        );
        h.insert(
            "m2_vs_m1_trans_reduction_pct".into(),
            reduction_pct(m2.trans_norm_of_means_mm, m1.trans_norm_of_means_mm),
        );
        h.insert(
            "m2_vs_mh_rot_reduction_pct".into(),
            reduction_pct(m2.rot_norm_of_means_deg, mh.rot_norm_of_means_deg),
        );
        h.insert(
            "m2_vs_mh_trans_reduction_pct".into(),
            reduction_pct(m2.trans_norm_of_means_mm, mh.trans_norm_of_means_mm),
        );
        for (k, r) in [("mh", mh), ("m1", m1), ("m2", m2), ("hybrid", hy)] {
            h.insert(format!("c0_{k}_mse_total"), r.eval.mse_total);
            h.insert(format!("c0_{k}_rot_norm_deg"), r.rot_norm_of_means_deg);
            h.insert(format!("c0_{k}_trans_norm_mm"), r.trans_norm_of_means_mm);
            h.insert(format!("c0_{k}_mpe_px"), r.eval.mpe_px);
        }
        for (r, n) in s.hybrid_few.iter().zip(s.config.hybrid_n.iter().map(|n| n.pow(3))) {
            h.insert(format!("c0_hybrid_{n}_mse_total"), r.eval.mse_total);
            h.insert(format!("c0_hybrid_{n}_rot_norm_deg"), r.rot_norm_of_means_deg);
            h.insert(format!("c0_hybrid_{n}_trans_norm_mm"), r.trans_norm_of_means_mm);
            h.insert(format!("c0_hybrid_{n}_mpe_px"), r.eval.mpe_px);
            h.insert(format!("c0_hybrid_{n}_mse_over_m1_full"), r.eval.mse_total / m1.eval.mse_total);
            h.insert(format!("c0_hybrid_{n}_mse_over_m2_full"), r.eval.mse_total / m2.eval.mse_total);
        }
        let n = s.config.table_n.pow(3);
        for u in &s.config.finetune_units {
            let key = u.to_lowercase();
            if let Some(m4) = find(&s.table3, u, "M4f") {
                h.insert(format!("{key}_m4f_{n}_mse_total"), m4.eval.mse_total);
                h.insert(format!("{key}_m4f_{n}_rot_norm_deg"), m4.rot_norm_of_means_deg);
                h.insert(format!("{key}_m4f_{n}_mpe_px"), m4.eval.mpe_px);
                h.insert(format!("{key}_m4f_{n}_mse_over_c0_m1_full"), m4.eval.mse_total / m1.eval.mse_total);
            }
            if let Some(hf) = find(&s.table3, u, "hybrid") {
                h.insert(format!("{key}_hybrid_{n}_mse_total"), hf.eval.mse_total);
                h.insert(format!("{key}_hybrid_{n}_mpe_px"), hf.eval.mpe_px);
            }
        }
        for p in s.fig7.iter().filter(|p| p.label == "hybrid" && p.n_per_axis == 4) {
            h.insert(format!("{}_hybrid_64_mse_total", p.unit.to_lowercase()), p.mse_total);
        }
    }
    for (key, label, full) in
        [("m2", "M2' (restricted)", "M2 (full range)"), ("hybrid", "hybrid' (restricted)", "hybrid (full range)")]
    {
        let full = s.extrapolation.iter().find(|r| r.label == full);
        if let Some(r) = s.extrapolation.iter().find(|r| r.label == label) {
            h.insert(format!("extrap_{key}_restricted_mse_inside"), r.mse_inside);
            h.insert(format!("extrap_{key}_restricted_mse_outside"), r.mse_outside);
            h.insert(format!("extrap_{key}_restricted_outside_over_inside"), r.outside_over_inside);
            if let Some(f) = full {
                h.insert(format!("extrap_{key}_restricted_outside_over_full_outside"), r.mse_outside / f.mse_outside);
            }
        }
    }
    h
}

fn verdict(all: bool, any: bool) -> String {
    if all {
        "holds".into()
    } else if any {
        "partly holds".into()
    } else {
        "does not hold".into()
    }
}

fn conclusions(s: &PaperSummary) -> Vec<Conclusion> {
    let mut out = vec![];
    let t2 = |l: &str| find(&s.table2, "C0", l);
    let (Some(mh), Some(m1), Some(m2)) = (t2("M_h"), t2("M1"), t2("M2")) else {
        return out;
    };
    let (rr, tr) = (
        reduction_pct(m2.rot_norm_of_means_deg, m1.rot_norm_of_means_deg),
        reduction_pct(m2.trans_norm_of_means_mm, m1.trans_norm_of_means_mm),
    );
    out.push(Conclusion {
        claim: "M2 (rotation and translation branches, 2:1 loss) beats M1".into(),
        paper: "rotation error norm -17 %, translation -3.9 %; MPE 2.66 -> 2.06 px (C0)".into(),
        ours: format!(
            "rotation {:.4} -> {:.4} deg ({:+.1} %), translation {:.4} -> {:.4} mm ({:+.1} %); MSE_total {:.5} -> {:.5}; MPE {:.2} -> {:.2} px",
            m1.rot_norm_of_means_deg, m2.rot_norm_of_means_deg, -rr, m1.trans_norm_of_means_mm, m2.trans_norm_of_means_mm, -tr,
            m1.eval.mse_total, m2.eval.mse_total, m1.eval.mpe_px, m2.eval.mpe_px
        ),
        verdict: verdict(rr > 0.0 && tr > 0.0, rr > 0.0 || tr > 0.0),
    });
    let (rh, th) = (
        reduction_pct(m2.rot_norm_of_means_deg, mh.rot_norm_of_means_deg),
        reduction_pct(m2.trans_norm_of_means_mm, mh.trans_norm_of_means_mm),
    );
    out.push(Conclusion {
        claim: "M2 beats nominal kinematics + hand-eye (M_h) by a wide margin".into(),
        paper: "rotation error norm -93 %, translation -69 %".into(),
        ours: format!(
            "rotation {:.4} -> {:.4} deg ({:+.1} %), translation {:.4} -> {:.4} mm ({:+.1} %) (criterion: both reduced by more than half)",
            mh.rot_norm_of_means_deg, m2.rot_norm_of_means_deg, -rh, mh.trans_norm_of_means_mm, m2.trans_norm_of_means_mm, -th
        ),
        verdict: verdict(rh > 50.0 && th > 50.0, rh > 0.0 && th > 0.0),
    });
    let n = s.config.table_n.pow(3);
    let mut per_unit = vec![];
    let (mut wins, mut units) = (0, 0);
    let (mut as_is_wins, mut as_is_txt) = (0, vec![]);
    for u in &s.config.finetune_units {
        let g = |l: &str| find(&s.table3, u, l);
        if let (Some(m4), Some(m1f), Some(m2f)) = (g("M4f"), g("M1f"), g("M2f")) {
            units += 1;
            let best = m1f.rot_norm_of_means_deg.min(m2f.rot_norm_of_means_deg);
            if m4.rot_norm_of_means_deg < best {
                wins += 1;
            }
            per_unit.push(format!(
                "{u}: rotation M1f {:.4} / M2f {:.4} / M4f {:.4} deg (M4f vs M2f {:+.1} %), MSE_total {:.5} / {:.5} / {:.5}",
                m1f.rot_norm_of_means_deg,
                m2f.rot_norm_of_means_deg,
                m4.rot_norm_of_means_deg,
                -reduction_pct(m4.rot_norm_of_means_deg, m2f.rot_norm_of_means_deg),
                m1f.eval.mse_total,
                m2f.eval.mse_total,
                m4.eval.mse_total
            ));
            if let Some(a) = g("M2 of C0 as is") {
                let ratio = a.eval.mpe_px / m4.eval.mpe_px;
                if ratio >= 2.0 {
                    as_is_wins += 1;
                }
                as_is_txt.push(format!(
                    "{u}: MPE {:.2} px as is vs {:.2} px after M4f ({ratio:.1}x); MSE_total {:.4} vs {:.5}",
                    a.eval.mpe_px, m4.eval.mpe_px, a.eval.mse_total, m4.eval.mse_total
                ));
            }
        }
    }
    if units > 0 {
        out.push(Conclusion {
            claim: format!("With {n} fine-tuning samples M4f beats M1f and M2f"),
            paper: "mean rotation |error| on C1/C2/C3: M4f <= M2f < M1f (Table III)".into(),
            ours: format!("M4f has the lowest rotation error norm on {wins} of {units} units. {}", per_unit.join("; ")),
            verdict: verdict(wins == units, wins > 0),
        });
        out.push(Conclusion {
            claim: "C0's model applied as is to a new unit is much worse than after fine-tuning".into(),
            paper: "C1: MPE 9.61 px with C0's model vs 3.47 px with M4f (343 samples)".into(),
            ours: format!("{} (criterion: at least 2x on every unit)", as_is_txt.join("; ")),
            verdict: verdict(as_is_wins == units, as_is_wins > 0),
        });
    }
    let ex = |l: &str| s.extrapolation.iter().find(|r| r.label == l);
    if let (Some(f), Some(r)) = (ex("M2 (full range)"), ex("M2' (restricted)")) {
        let vs_full = r.mse_outside / f.mse_outside;
        out.push(Conclusion {
            claim: "Training on the restricted range degrades about 10x outside it".into(),
            paper: "M2' MSE_total outside 1.904 vs 0.222 with full training (8.6x), 24x its own inside error (0.079); inside 0.079 vs 0.088".into(),
            ours: format!(
                "M2' outside {:.4} vs {:.4} with full training ({vs_full:.1}x), {:.1}x its inside error ({:.5}); inside {:.5} vs {:.5} (criterion: >= 5x holds, >= 2x partly)",
                r.mse_outside, f.mse_outside, r.outside_over_inside, r.mse_inside, r.mse_inside, f.mse_inside
            ),
            verdict: verdict(vs_full >= 5.0, vs_full >= 2.0),
        });
    }
    if let Some(m) = s.fig8.iter().find(|m| m.unit == "C0" && m.label == "M_h") {
        let ratio = m.outer_mpe_px / m.centre_mpe_px;
        out.push(Conclusion {
            claim: "M_h errors grow from the centre of the workspace outwards".into(),
            paper: "Fig. 8: M_h projection error lowest at the centre, growing outwards".into(),
            ours: format!(
                "M_h MPE {:.2} px in cells with max(|alpha|, |gamma|) <= {CENTRE_DEG} deg, {:.2} px beyond {OUTER_DEG} deg ({ratio:.2}x) (criterion: > 1.25x)",
                m.centre_mpe_px, m.outer_mpe_px
            ),
            verdict: verdict(ratio > 1.25, ratio > 1.0),
        });
    }
    out
}

// ---- report.md --------------------------------------------------------------------------------

macro_rules! w {
    ($s:expr, $($t:tt)*) => {{ let _ = writeln!($s, $($t)*); }};
}

fn means(r: &ModelResult) -> [f64; 6] {
    let a = |m: &std::collections::BTreeMap<&'static str, crate::metrics::AxisStats>, k: &str| m[k].mean;
    [
        a(&r.eval.rot_deg, "alpha"),
        a(&r.eval.rot_deg, "beta"),
        a(&r.eval.rot_deg, "gamma"),
        a(&r.eval.trans_mm, "x"),
        a(&r.eval.trans_mm, "y"),
        a(&r.eval.trans_mm, "z"),
    ]
}

fn maxes(r: &ModelResult) -> [f64; 6] {
    let a = |m: &std::collections::BTreeMap<&'static str, crate::metrics::AxisStats>, k: &str| m[k].max;
    [
        a(&r.eval.rot_deg, "alpha"),
        a(&r.eval.rot_deg, "beta"),
        a(&r.eval.rot_deg, "gamma"),
        a(&r.eval.trans_mm, "x"),
        a(&r.eval.trans_mm, "y"),
        a(&r.eval.trans_mm, "z"),
    ]
}

fn norm3(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

/// Four significant digits, plain notation.
fn g(v: f64) -> String {
    if !v.is_finite() {
        return "n/a".into();
    }
    if v == 0.0 {
        return "0".into();
    }
    let d = (3 - v.abs().log10().floor() as i32).clamp(0, 9) as usize;
    format!("{v:.d$}")
}

fn row6(v: &[f64; 6]) -> String {
    v.iter().map(|x| format!("{x:.3}")).collect::<Vec<_>>().join(" | ")
}

fn result_header(s: &mut String, first: &str) {
    w!(s, "| {first} | alpha | beta | gamma | x | y | z | rot norm | trans norm | MSE_total | MPE px | train samples | epochs |");
    w!(s, "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |");
}

fn result_row(s: &mut String, name: &str, r: &ModelResult) {
    w!(
        s,
        "| {name} | {} | {:.3} | {:.3} | {} | {:.2} | {} | {} |",
        row6(&means(r)),
        r.rot_norm_of_means_deg,
        r.trans_norm_of_means_mm,
        g(r.eval.mse_total),
        r.eval.mpe_px,
        r.train_samples,
        if r.epochs.is_empty() {
            "-".into()
        } else {
            r.epochs.iter().map(|e| e.to_string()).collect::<Vec<_>>().join("/")
        }
    );
}

fn paper_row(s: &mut String, name: &str, v: &[f64; 6]) {
    w!(s, "| *paper {name}* | {} | {:.3} | {:.3} | | | | |", row6(v), norm3(&v[..3]), norm3(&v[3..]));
}

fn floor_row(s: &mut String, sum: &PaperSummary, unit: &str) {
    if let Some((_, f)) = sum.noise_floor_mse.iter().find(|(u, _)| u == unit) {
        w!(s, "| *measurement noise alone* | | | | | | | | | ~{} | | | |", g(*f));
    }
}

fn report_md(s: &PaperSummary) -> String {
    let c = &s.config;
    let mut r = String::new();
    w!(r, "# The paper's experiments on our simulated units C0..C3\n");
    w!(
        r,
        "Generated by `abvs calib paper{}` (seed {}) in {:.0} s ({:.1} min). All numbers are also in `summary.json`. \
         Paper: Wang et al., RA-L 10(7) 2025 (shared/reference/paper.md).\n",
        if c.quick { " --quick" } else { "" },
        c.seed,
        s.seconds,
        s.seconds / 60.0
    );
    if c.quick {
        w!(r, "**Quick mode**: smaller grids and fewer epochs than the paper; the numbers only show that the pipeline works.\n");
    }
    w!(r, "## Setup\n");
    w!(
        r,
        "- Units: `fixtures/units/c0..c3.toml` (drawn with the magnitudes of effects.md). Their ideal-vs-measured deviation \
         reaches about {:.1} deg and {:.1} mm; the paper's units reach 7.2 deg and 4.9-12.7 mm, so our units are \
         closer to nominal and every error below is expected to be smaller than the paper's.",
        s.data.iter().map(|d| d.max_dev_rot_deg).fold(0.0, f64::max),
        s.data.iter().map(|d| d.max_dev_trans_mm).fold(0.0, f64::max)
    );
    w!(
        r,
        "- Data (the paper's protocol): per unit one dense session on the {} deg commanded grid (5 % measurement dropout). \
         On C0 the samples commanded on the {} deg grid are the training set ({} samples), the rest is split 1:10 into \
         validation ({}) and test ({}); C1..C3 use the test part of their own dense session, split the same way. \
         Every model is scored on the **whole** test set (no subsampling).",
        c.dense_step_deg, c.train_step_deg, s.c0_split[0], s.c0_split[1], s.c0_split[2]
    );
    w!(
        r,
        "- Fine-tuning sets are separate sessions on n^3 commanded grids (n = {:?}), as the paper's 64..512, without dropout \
         (failed poses re-taken). Fine-tuning \
         uses only those samples (10 % of them held out for early stopping): a user who collected n^3 poses has no \
         other validation data. Their poses are not removed from the test sets (at most {:.1} % of a test set).",
        c.finetune_n,
        100.0 * (*c.finetune_n.iter().max().unwrap_or(&0) as f64).powi(3) / s.c0_split[2].max(1) as f64
    );
    w!(
        r,
        "- Training: Adam, batch 128, lr 1e-4, up to {} epochs, early stop after {} epochs without validation improvement \
         (the paper: 1000 / 100). M1: 7-layer MLP; M2: shared 4-layer trunk + rotation and translation branches, loss \
         2:1; M4f: M2's trunk frozen, branches duplicated for the PSC's internal and external regions (S_init and dS \
         searched on validation data); M_h: nominal kinematics + camera mount (hand-eye); hybrid (ours, not in the paper): \
         identification of the unit's static physical effects + a small residual network.",
        c.max_epochs, c.patience
    );
    w!(r, "- Columns: mean |error| per axis (deg, mm); rot/trans norm = Euclidean norm of the three per-axis means (how the paper's percentages follow from its Table II); MSE_total = mean squared error over samples and the six components (deg^2 and mm^2 together, eq. 11); MPE = mean projection error of the AprilGrid corners (px).\n");
    w!(r, "Sessions:\n");
    w!(r, "| unit | session | commanded | samples | max dev (deg) | max dev (mm) |");
    w!(r, "| --- | --- | --- | --- | --- | --- |");
    for d in &s.data {
        w!(
            r,
            "| {} | {} | {} | {} | {:.2} | {:.2} |",
            d.unit,
            d.session,
            d.commanded,
            d.written,
            d.max_dev_rot_deg,
            d.max_dev_trans_mm
        );
    }

    w!(r, "\n## Table II: C0, trained on the {} deg grid\n", c.train_step_deg);
    result_header(&mut r, "method");
    for res in &s.table2 {
        result_row(&mut r, &res.label, res);
        if let Some((_, v)) = PAPER_T2.iter().find(|(l, _)| *l == res.label) {
            paper_row(&mut r, &res.label, v);
        }
    }
    floor_row(&mut r, s, "C0");
    w!(r, "\n99.9th percentile of |error| (the paper's \"max\"):\n");
    w!(r, "| method | alpha | beta | gamma | x | y | z |");
    w!(r, "| --- | --- | --- | --- | --- | --- | --- |");
    for res in &s.table2 {
        w!(r, "| {} | {} |", res.label, row6(&maxes(res)));
    }
    w!(r, "| *paper M2* | {} |", row6(&PAPER_M2_MAX));

    w!(r, "\n## Hybrid from scratch on C0 with few samples\n");
    w!(r, "The paper needed about 4,500 samples for an acceptable projection error without fine-tuning. Our hybrid from n^3 grids, next to the full-grid networks:\n");
    result_header(&mut r, "model");
    for res in s.table2.iter().filter(|x| x.label == "M1" || x.label == "M2" || x.label == "hybrid") {
        result_row(&mut r, &format!("{} ({} samples)", res.label, res.train_samples), res);
    }
    for res in &s.hybrid_few {
        result_row(&mut r, &res.label, res);
    }
    floor_row(&mut r, s, "C0");

    w!(r, "\n## Table III: C1..C3 with {} fine-tuning samples\n", c.table_n.pow(3));
    w!(r, "M_h is fitted on the unit's own {0} samples; M1f, M2f, M4f fine-tune C0's M1 / M2; hybrid re-identifies C0's hybrid physics on the {0} samples and trains a new residual.\n", c.table_n.pow(3));
    for u in &c.finetune_units {
        w!(r, "**{u}**\n");
        result_header(&mut r, "method");
        let paper = PAPER_T3.iter().find(|(n, _)| n == u).map(|(_, v)| v);
        let paper_tr = PAPER_T3_M4F_TRANS.iter().find(|(n, _)| n == u).map(|(_, v)| v);
        for res in s.table3.iter().filter(|x| &x.unit == u) {
            result_row(&mut r, &res.label, res);
            let pi = PAPER_T3_LABELS.iter().position(|l| *l == res.label);
            if let (Some(p), Some(i)) = (paper, pi) {
                let v = p[i];
                let tr = if res.label == "M4f" {
                    paper_tr.map(|t| format!("{:.3} | {:.3} | {:.3}", t[0], t[1], t[2]))
                } else {
                    None
                };
                w!(
                    r,
                    "| *paper {}* | {:.2} | {:.2} | {:.2} | {} | {:.3} | | | | | |",
                    res.label,
                    v[0],
                    v[1],
                    v[2],
                    tr.unwrap_or_else(|| " | | ".into()),
                    norm3(&v)
                );
            }
        }
        floor_row(&mut r, s, u);
        w!(r, "");
    }

    w!(r, "## Fig. 7: MSE_total vs fine-tuning size\n");
    w!(r, "Test set split by each size's M4f PSC threshold: internal S <= S_init, external S > S_init (the same split for M2f and hybrid of that size).\n");
    for u in &c.finetune_units {
        w!(r, "![Fig. 7 {u}](fig7_{}.png)\n", u.to_lowercase());
    }
    w!(r, "| unit | samples | S_init | internal share | M4f int | M4f ext | M4f all | M2f int | M2f ext | M2f all | hybrid int | hybrid ext | hybrid all |");
    w!(r, "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |");
    for u in &c.finetune_units {
        for &n in &c.finetune_n {
            let p = |l: &str| s.fig7.iter().find(|p| &p.unit == u && p.n_per_axis == n && p.label == l);
            let (Some(a), Some(b), Some(h)) = (p("M4f"), p("M2f"), p("hybrid")) else {
                continue;
            };
            let tri = |x: &Fig7Point| format!("{} | {} | {}", g(x.mse_internal), g(x.mse_external), g(x.mse_total));
            w!(
                r,
                "| {u} | {} | {:.4} | {:.0} % | {} | {} | {} |",
                a.samples,
                a.s_init,
                100.0 * a.internal_fraction,
                tri(a),
                tri(b),
                tri(h)
            );
        }
    }

    let (mut m4_wins, mut pts, mut int_better) = (0, 0, 0);
    for p in s.fig7.iter().filter(|p| p.label == "M4f") {
        if let Some(q) = s.fig7.iter().find(|q| q.label == "M2f" && q.unit == p.unit && q.n_per_axis == p.n_per_axis) {
            pts += 1;
            m4_wins += usize::from(p.mse_total < q.mse_total);
            int_better += usize::from(p.mse_internal < p.mse_external);
        }
    }
    let fall = |l: &str| -> Vec<String> {
        c.finetune_units
            .iter()
            .filter_map(|u| {
                let v: Vec<&Fig7Point> = s.fig7.iter().filter(|p| &p.unit == u && p.label == l).collect();
                let (a, b) = (v.first()?, v.last()?);
                Some(format!("{u} {:.1}x", a.mse_total / b.mse_total))
            })
            .collect()
    };
    w!(
        r,
        "\nObservations: M4f has a lower MSE_total than M2f at {m4_wins} of {pts} (unit, size) points, and a lower internal than \
         external error at {int_better} of {pts}. From the smallest to the largest set MSE_total falls by {} (M4f), {} (M2f), \
         {} (hybrid, which starts at the noise floor).",
        fall("M4f").join(", "),
        fall("M2f").join(", "),
        fall("hybrid").join(", ")
    );

    w!(r, "\n## Extrapolation: trained on alpha, gamma +-20, beta +-12 deg ({} deg step)\n", c.restricted_step_deg);
    w!(r, "MSE_total on the C0 test set inside the range (by commanded pose), outside it, and on the whole set; the paper's values for M2 in italics.\n");
    w!(r, "| model | training | samples | inside | outside | whole | outside / inside |");
    w!(r, "| --- | --- | --- | --- | --- | --- | --- |");
    for e in &s.extrapolation {
        w!(
            r,
            "| {} | {} | {} | {} | {} | {} | {:.1}x |",
            e.label,
            e.trained_on,
            e.train_samples,
            g(e.mse_inside),
            g(e.mse_outside),
            g(e.mse_whole),
            e.outside_over_inside
        );
        if let Some(p) = e.paper {
            w!(r, "| *paper {}* | | | *{}* | *{}* | *{}* | *{:.1}x* |", e.label, p[0], p[1], p[2], p[1] / p[0]);
        }
    }

    w!(r, "\n## Fig. 8: mean projection error over alpha x gamma\n");
    w!(r, "Per test sample MPE, mean over beta in 2 x 2 deg cells of the commanded alpha (x) and gamma (y); one colour scale per figure (0 to its largest cell).\n");
    w!(r, "| figure | model | MPE px | centre (<= {CENTRE_DEG} deg) | outer (> {OUTER_DEG} deg) | outer / centre | file |");
    w!(r, "| --- | --- | --- | --- | --- | --- | --- |");
    for m in &s.fig8 {
        w!(
            r,
            "| {} | {} | {:.2} | {:.2} | {:.2} | {:.2} | [{}]({}) |",
            m.figure,
            m.label,
            m.mean_mpe_px,
            m.centre_mpe_px,
            m.outer_mpe_px,
            m.outer_mpe_px / m.centre_mpe_px,
            m.file,
            m.file
        );
    }
    w!(r, "");
    for m in &s.fig8 {
        w!(r, "![{} {}]({})", m.unit, m.label, m.file);
    }

    w!(r, "\n## Conclusions: which of the paper's claims hold on our units\n");
    for k in &s.conclusions {
        w!(r, "- **{}: {}.** Paper: {}. Ours: {}.", k.claim, k.verdict, k.paper, k.ours);
    }
    w!(r, "\nBeyond the paper (closing-note numbers):\n");
    let h = &s.headline;
    let hv = |k: &str| h.get(k).copied().unwrap_or(f64::NAN);
    for (res, n) in s.hybrid_few.iter().zip(c.hybrid_n.iter().map(|n| n.pow(3))) {
        w!(
            r,
            "- hybrid from {n} C0 samples: MSE_total {} = {}x M1 (full grid) and {}x M2 (full grid); MPE {:.2} px.",
            g(res.eval.mse_total),
            g(hv(&format!("c0_hybrid_{n}_mse_over_m1_full"))),
            g(hv(&format!("c0_hybrid_{n}_mse_over_m2_full"))),
            res.eval.mpe_px
        );
    }
    for u in &c.finetune_units {
        let k = u.to_lowercase();
        let n = c.table_n.pow(3);
        w!(
            r,
            "- {u}: M4f({n}) MSE_total {} = {:.2}x C0's M1 on the full grid; hybrid({n}) {}; hybrid(64) {}.",
            g(hv(&format!("{k}_m4f_{n}_mse_total"))),
            hv(&format!("{k}_m4f_{n}_mse_over_c0_m1_full")),
            g(hv(&format!("{k}_hybrid_{n}_mse_total"))),
            g(hv(&format!("{k}_hybrid_64_mse_total")))
        );
    }
    w!(
        r,
        "- Extrapolation: restricted M2' outside/inside {:.1}x (outside vs full-range M2: {:.1}x); restricted hybrid' outside/inside {:.1}x (vs full-range hybrid: {:.1}x).",
        hv("extrap_m2_restricted_outside_over_inside"),
        hv("extrap_m2_restricted_outside_over_full_outside"),
        hv("extrap_hybrid_restricted_outside_over_inside"),
        hv("extrap_hybrid_restricted_outside_over_full_outside")
    );

    w!(r, "\n## Why our numbers differ from the paper's\n");
    let t2 = |l: &str| find(&s.table2, "C0", l);
    if let (Some(mh), Some(m1), Some(m2)) = (t2("M_h"), t2("M1"), t2("M2")) {
        let ep = |x: &ModelResult| x.epochs.first().copied().unwrap_or(0);
        let capped = ep(m1) >= c.max_epochs || ep(m2) >= c.max_epochs;
        w!(
            r,
            "- Our units deviate less from nominal (at most {:.1} deg here vs 7.2 deg in the paper), and most of it is the \
             camera mount, which M_h (hand-eye) identifies: C0's M_h reaches {:.3} deg rotation norm against the paper's \
             2.941 deg. M1 / M2 learn the whole forward kinematics from the same {} samples and end at {:.3} / {:.3} deg \
             (paper: 0.246 / 0.204 deg){}. {}",
            s.data.iter().map(|d| d.max_dev_rot_deg).fold(0.0, f64::max),
            mh.rot_norm_of_means_deg,
            m1.train_samples,
            m1.rot_norm_of_means_deg,
            m2.rot_norm_of_means_deg,
            if capped {
                format!(
                    "; they ran to the {}-epoch limit ({} / {} epochs) with the validation loss still improving within the last {}",
                    c.max_epochs,
                    ep(m1),
                    ep(m2),
                    c.patience
                )
            } else {
                format!("; they early-stopped at {} / {} epochs", ep(m1), ep(m2))
            },
            if mh.rot_norm_of_means_deg < m2.rot_norm_of_means_deg {
                "So on our units hand-eye calibration beats the networks, the opposite of the paper's ranking."
            } else {
                "The networks still beat hand-eye calibration, as in the paper, by a smaller margin."
            }
        );
    }
    let floor = s.noise_floor_mse.iter().find(|(u, _)| u == "C0").map_or(f64::NAN, |x| x.1);
    let few = s.hybrid_few.first().map_or(f64::NAN, |x| x.eval.mse_total);
    let hyr =
        s.extrapolation.iter().find(|e| e.label.starts_with("hybrid'")).map_or(f64::NAN, |e| e.outside_over_inside);
    w!(
        r,
        "- The hybrid identifies the static effects of the same unit model the simulator draws from (effects.md). On \
         simulated units that is an upper bound: from {} samples its C0 MSE_total is {} against a measurement-noise floor \
         of ~{}, and trained on the restricted range its error outside is {:.2}x the error inside. On a real unit, \
         effects outside the model are left to its small residual network, which extrapolates no better than M2.",
        c.hybrid_n.first().map_or(0, |n| n.pow(3)),
        g(few),
        g(floor),
        hyr
    );
    w!(
        r,
        "- MSE_total adds deg^2 and mm^2; our translation errors are small (the camera offset is identified or learnt well), \
         so the networks' MSE_total is dominated by rotation here, the paper's by translation (0.4 mm mean errors)."
    );
    w!(
        r,
        "- Fine-tuning validates on 10 % of the n^3 samples (a few dozen), so early stopping and M4f's S_init / dS search \
         are noisy at the small sizes; the paper does not say what it validated fine-tuning on."
    );

    w!(r, "\n## Run time\n");
    w!(r, "| stage | s |");
    w!(r, "| --- | --- |");
    for (st, t) in &s.stages {
        w!(r, "| {st} | {t:.1} |");
    }
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_membership_and_split() {
        assert!(on_grid(&[-30.0, -15.0, 30.0], 3.0));
        assert!(on_grid(&[-27.0, 0.0, 3.0], 3.0));
        assert!(!on_grid(&[-29.0, 0.0, 3.0], 3.0));
        // The 6 deg grid's beta values are -15, -9, ... (the simulator's grids start at -range).
        assert!(on_grid(&[0.0, -9.0, 6.0], 6.0) && !on_grid(&[0.0, -12.0, 6.0], 6.0));
        assert!(inside_restricted(&[20.0, -12.0, 0.0]) && !inside_restricted(&[21.0, 0.0, 0.0]));
    }

    #[test]
    fn units_parse_and_differ() {
        let u: Vec<UnitModel> = ["C0", "C1", "C2", "C3"].iter().map(|n| paper_unit(n).unwrap()).collect();
        assert_eq!(u[0].name, "C0");
        assert_ne!(u[0].to_toml_string(), u[1].to_toml_string());
        assert!(paper_unit("C4").is_err());
    }

    #[test]
    fn significant_digits() {
        assert_eq!(g(0.012345), "0.01235");
        assert_eq!(g(1.904), "1.904");
        assert_eq!(g(123.4), "123.4");
        assert_eq!(g(f64::NAN), "n/a");
    }
}
