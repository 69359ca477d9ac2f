//! The calibration methods: `mh`, `m1`, `m2` (fit from scratch), `m1f`, `m2f`, `m4f`
//! (fine-tune a network of another unit) and `hybrid` (physics identification + residual
//! network; fits and fine-tunes). Each returns [`ModelParts`] for [`crate::model::save_model`].
use crate::error::{CalibError, Result};
use crate::identify::{fit_unit, static_effects, FitOptions};
use crate::metrics::evaluate;
use crate::mlp::{train, Affine, Net, TrainConfig};
use crate::model::{FkModel, Manifest, ModelParts, PscSplit, TrainingInfo};
use crate::mpe::Target;
use abvs_eye::dataset::Dataset;
use abvs_eye::psc::percentile;
use abvs_eye::unit::{Effect, UnitModel};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::time::Instant;

/// Fewest samples any method accepts: below this no fit is meaningful.
pub const MIN_SAMPLES: usize = 16;

/// The methods are named in abvs-fk (manifests carry them); re-exported for the callers here.
pub use abvs_fk::method::Method;

/// Training settings shared by the methods (the paper's defaults).
#[derive(Debug, Clone)]
pub struct FitConfig {
    pub max_epochs: usize,
    pub patience: usize,
    pub lr: f64,
    pub seed: u64,
    /// Hidden width of the paper's networks (7 layers in all).
    pub hidden: usize,
    /// Hidden width of the hybrid's residual network (4 layers).
    pub residual_hidden: usize,
    /// Fraction of the training set held out for early stopping when no validation set is given.
    pub val_fraction: f64,
}

impl FitConfig {
    /// Sizes and rates a fit can use (a zero width would panic inside the network code).
    pub fn check(&self) -> Result<()> {
        let bad = |what: &str| Err(CalibError::Invalid(format!("fit config: {what}")));
        if self.hidden == 0 || self.residual_hidden == 0 {
            return bad("hidden widths must be at least 1");
        }
        if self.max_epochs == 0 {
            return bad("max_epochs must be at least 1");
        }
        if !(self.lr.is_finite() && self.lr > 0.0) {
            return bad("the learning rate must be a positive number");
        }
        if !(self.val_fraction > 0.0 && self.val_fraction < 1.0) {
            return bad("val_fraction must be in (0, 1)");
        }
        Ok(())
    }
}

impl Default for FitConfig {
    fn default() -> Self {
        FitConfig {
            max_epochs: 1000,
            patience: 100,
            lr: 1e-4,
            seed: 0,
            hidden: 64,
            residual_hidden: 32,
            val_fraction: 0.1,
        }
    }
}

/// Progress of long work: (what, step, total, train loss, val loss).
pub type Progress<'a> = &'a mut dyn FnMut(&str, usize, usize, f64, f64);

fn check(data: &Dataset, what: &str) -> Result<()> {
    if data.len() < MIN_SAMPLES {
        return Err(CalibError::Data(format!("{what}: {} samples, at least {MIN_SAMPLES} needed", data.len())));
    }
    Ok(())
}

fn xy(data: &Dataset) -> (Vec<[f64; 3]>, Vec<[f64; 6]>) {
    (data.samples.iter().map(|s| s.theta_deg).collect(), data.samples.iter().map(|s| s.pose).collect())
}

/// Splits off a random validation subset (both parts keep acquisition order).
pub fn split_validation(data: &Dataset, fraction: f64, seed: u64) -> (Dataset, Dataset) {
    let is_val = validation_mask(data.len(), fraction, seed);
    let pick = |v: bool| Dataset {
        samples: data.samples.iter().zip(&is_val).filter(|(_, &f)| f == v).map(|(s, _)| s.clone()).collect(),
        extra_columns: data.extra_columns.clone(),
    };
    (pick(false), pick(true))
}

/// Which of n samples form a seeded random validation subset of the given fraction.
pub fn validation_mask(n: usize, fraction: f64, seed: u64) -> Vec<bool> {
    let nv = ((n as f64 * fraction).round() as usize).clamp(1, n.saturating_sub(1).max(1));
    let mut idx: Vec<usize> = (0..n).collect();
    idx.shuffle(&mut ChaCha8Rng::seed_from_u64(seed ^ 0x5eed));
    let mut is_val = vec![false; n];
    for &i in idx.iter().take(nv) {
        is_val[i] = true;
    }
    is_val
}

fn train_val<'d>(train_data: &'d Dataset, val: Option<&'d Dataset>, cfg: &FitConfig) -> (Dataset, Dataset) {
    match val {
        Some(v) => (train_data.clone(), v.clone()),
        None => split_validation(train_data, cfg.val_fraction, cfg.seed),
    }
}

fn train_cfg(cfg: &FitConfig, weights: [f64; 6], frozen: usize) -> TrainConfig {
    TrainConfig {
        lr: cfg.lr,
        max_epochs: cfg.max_epochs,
        patience: cfg.patience,
        seed: cfg.seed,
        output_weights: weights,
        frozen_layers: frozen,
        ..TrainConfig::default()
    }
}

const W_M1: [f64; 6] = [1.0; 6];
/// The paper's 2:1 rotation : translation loss weights (eq. 5-7).
const W_M2: [f64; 6] = [2.0, 2.0, 2.0, 1.0, 1.0, 1.0];

fn train_net(
    net: &mut Net,
    tr: &Dataset,
    va: &Dataset,
    tc: &TrainConfig,
    what: &str,
    progress: Progress,
) -> Result<(usize, f64)> {
    let (x, y) = xy(tr);
    let (xv, yv) = xy(va);
    let max = tc.max_epochs;
    let rep = train(net, &x, &y, Some((&xv, &yv)), tc, &mut |e, a, b| progress(what, e, max, a, b))?;
    Ok((rep.epochs, rep.best_val_loss))
}

fn finish(mut m: Manifest, train_data: &Dataset, val: &Dataset, cfg: &FitConfig, t0: Instant) -> Manifest {
    m.training.data_hash = train_data.content_hash();
    m.training.samples = train_data.len();
    m.training.val_samples = val.len();
    m.training.seed = cfg.seed;
    m.training.seconds = t0.elapsed().as_secs_f64();
    m.training.range_deg = TrainingInfo::range_of(train_data);
    m
}

/// The parts of a one-network model (m1, m2, m1f, m2f), with its validation metrics.
#[allow(clippy::too_many_arguments)]
fn single_net(
    method: Method,
    net: Net,
    epochs: usize,
    base: Option<String>,
    tr: &Dataset,
    va: &Dataset,
    cfg: &FitConfig,
    t0: Instant,
) -> ModelParts {
    let mut m = Manifest::new(method);
    m.training.epochs = vec![epochs];
    m.training.base = base;
    let (xv, yv) = xy(va);
    m.validation = Some(serde_json::to_value(evaluate(&net.eval_batch(&xv), &yv, &Target::paper())).expect("json"));
    ModelParts { manifest: finish(m, tr, va, cfg, t0), nets: vec![("net".into(), net)], unit: None }
}

/// Fits a model from scratch: mh, m1, m2 or hybrid.
pub fn fit(
    method: Method,
    data: &Dataset,
    val: Option<&Dataset>,
    cfg: &FitConfig,
    progress: Progress,
) -> Result<ModelParts> {
    check(data, "training data")?;
    cfg.check()?;
    if val.is_some_and(|v| v.is_empty()) {
        // an empty validation set would be recorded as a perfect score
        return Err(CalibError::Data("validation data: no samples".into()));
    }
    let t0 = Instant::now();
    match method {
        Method::Mh => physics(method, &UnitModel::nominal(), &[Effect::CameraMount], data, val, cfg, None, progress),
        Method::Hybrid => physics(method, &UnitModel::nominal(), &static_effects(), data, val, cfg, None, progress),
        Method::M1 | Method::M2 => {
            let (tr, va) = train_val(data, val, cfg);
            let (x, y) = xy(&tr);
            let xin: Vec<&[f64]> = x.iter().map(|v| v.as_slice()).collect();
            let yout: Vec<&[f64]> = y.iter().map(|v| v.as_slice()).collect();
            let (ni, no) = (Affine::fit(&xin, 3), Affine::fit(&yout, 6));
            let (mut net, w) = if method == Method::M1 {
                (Net::m1(cfg.hidden, 7, ni, no, cfg.seed), W_M1)
            } else {
                (Net::m2(cfg.hidden, 4, 3, ni, no, cfg.seed), W_M2)
            };
            let (epochs, _) = train_net(&mut net, &tr, &va, &train_cfg(cfg, w, 0), method.name(), progress)?;
            Ok(single_net(method, net, epochs, None, &tr, &va, cfg, t0))
        }
        _ => Err(CalibError::Invalid(format!(
            "{} is a fine-tuning method: use finetune with a base model",
            method.name()
        ))),
    }
}

/// Physics identification (+ residual network for hybrid).
#[allow(clippy::too_many_arguments)]
fn physics(
    method: Method,
    start: &UnitModel,
    effects: &[Effect],
    data: &Dataset,
    val: Option<&Dataset>,
    cfg: &FitConfig,
    base: Option<String>,
    progress: Progress,
) -> Result<ModelParts> {
    let t0 = Instant::now();
    progress("physics", 0, 1, f64::NAN, f64::NAN);
    let opts = FitOptions { fit_all: method == Method::Mh, ..Default::default() };
    let fit = fit_unit(start, effects, data, &opts)?;
    progress("physics", 1, 1, fit.rms_rot_deg, fit.rms_trans_mm);
    let mut unit = fit.unit;
    unit.name = format!("{} fit", method.name());
    let mut m = Manifest::new(method);
    m.held_parameters =
        fit.held.iter().map(|h| format!("{} (confounded with {:?})", h.name, h.confounded_with)).collect();
    m.training.base = base;
    let mut nets = vec![];
    let (_, va_default) = split_validation(data, cfg.val_fraction, cfg.seed);
    let va = val.cloned().unwrap_or(va_default);
    if method == Method::Hybrid {
        // Residual network on what the physics leaves, kept only if it helps on held-out data.
        // Residuals are computed on the whole set in acquisition order (motion history), then split.
        let res_all = residual_targets(&unit, data)?;
        let x_all = xy(data).0;
        let (x, y, xv, yv) = match val {
            Some(v) => (x_all, res_all, xy(v).0, residual_targets(&unit, v)?),
            None => {
                let is_val = validation_mask(data.len(), cfg.val_fraction, cfg.seed);
                let part = |want: bool| -> (Vec<[f64; 3]>, Vec<[f64; 6]>) {
                    (0..data.len()).filter(|&i| is_val[i] == want).map(|i| (x_all[i], res_all[i])).unzip()
                };
                let ((x, y), (xv, yv)) = (part(false), part(true));
                (x, y, xv, yv)
            }
        };
        let xin: Vec<&[f64]> = x.iter().map(|v| v.as_slice()).collect();
        let yout: Vec<&[f64]> = y.iter().map(|v| v.as_slice()).collect();
        let mut net = Net::m1(cfg.residual_hidden, 4, Affine::fit(&xin, 3), Affine::fit(&yout, 6), cfg.seed);
        let tc = train_cfg(cfg, W_M1, 0);
        let max = tc.max_epochs;
        let rep = train(&mut net, &x, &y, Some((&xv, &yv)), &tc, &mut |e, a, b| progress("residual", e, max, a, b))?;
        m.training.epochs = vec![rep.epochs];
        let before: f64 = yv.iter().map(|r| r.iter().map(|v| v * v).sum::<f64>()).sum();
        let after: f64 = yv
            .iter()
            .zip(net.eval_batch(&xv))
            .map(|(r, p)| r.iter().zip(p).map(|(a, b)| (a - b).powi(2)).sum::<f64>())
            .sum();
        if after < 0.98 * before {
            nets.push(("residual".to_string(), net));
        }
    }
    // validation metrics of what is saved (the unit, plus the residual network when kept), as for every method
    let (xv, yv) = xy(&va);
    match unit.compile().and_then(|fk| fk.predict_dataset(&va)) {
        Ok(mut pred) => {
            if let Some((_, net)) = nets.first() {
                for (p, r) in pred.iter_mut().zip(net.eval_batch(&xv)) {
                    for k in 0..6 {
                        p[k] += r[k];
                    }
                }
            }
            m.validation = Some(serde_json::to_value(evaluate(&pred, &yv, &Target::paper())).expect("json"));
        }
        // a validation sample the fitted unit cannot reach: the fit stands, its metrics say why they are absent
        Err(e) => m.validation = Some(serde_json::json!({ "error": e.to_string() })),
    }
    let parts = ModelParts { manifest: finish(m, data, &va, cfg, t0), nets, unit: Some(unit) };
    Ok(parts)
}

/// P_meas - P_physics per sample.
fn residual_targets(unit: &UnitModel, data: &Dataset) -> Result<Vec<[f64; 6]>> {
    let pred = unit.compile()?.predict_dataset(data)?;
    Ok(data.samples.iter().zip(pred).map(|(s, p)| std::array::from_fn(|k| s.pose[k] - p[k])).collect())
}

/// Fine-tunes a model of another unit on this unit's (few) samples.
pub fn finetune(
    method: Method,
    base: &FkModel,
    data: &Dataset,
    val: Option<&Dataset>,
    cfg: &FitConfig,
    progress: Progress,
) -> Result<ModelParts> {
    check(data, "fine-tuning data")?;
    cfg.check()?;
    if val.is_some_and(|v| v.is_empty()) {
        // an empty validation set would be recorded as a perfect score
        return Err(CalibError::Data("validation data: no samples".into()));
    }
    let t0 = Instant::now();
    let base_id = Some(format!("{} ({})", base.method(), base.manifest.training.data_hash));
    let base_net = || -> Result<Net> {
        match base.native_net("net") {
            Some(n) => Ok(n.clone()),
            None => Err(CalibError::Mismatch(format!(
                "{} needs a base model with a native network 'net' (m1 or m2), got method {}",
                method.name(),
                base.method()
            ))),
        }
    };
    match method {
        Method::Mh => {
            let start = base.unit().cloned().unwrap_or_else(UnitModel::nominal);
            physics(method, &start, &[Effect::CameraMount], data, val, cfg, base_id, progress)
        }
        Method::Hybrid => {
            let start = base.unit().cloned().ok_or_else(|| {
                CalibError::Mismatch(format!(
                    "hybrid fine-tuning needs a physics base (mh or hybrid), got {}",
                    base.method()
                ))
            })?;
            physics(method, &start, &static_effects(), data, val, cfg, base_id, progress)
        }
        Method::M1f | Method::M2f => {
            // A fine-tuned base (m1f, m2f) fine-tunes again like its origin.
            let (want, ok) = if method == Method::M1f {
                ("m1", matches!(base.method(), Method::M1 | Method::M1f))
            } else {
                ("m2", matches!(base.method(), Method::M2 | Method::M2f))
            };
            if !ok {
                return Err(CalibError::Mismatch(format!(
                    "{} fine-tunes an {want} model, base is {}",
                    method.name(),
                    base.method()
                )));
            }
            let mut net = base_net()?;
            let (tr, va) = train_val(data, val, cfg);
            let w = if method == Method::M1f { W_M1 } else { W_M2 };
            let (epochs, _) = train_net(&mut net, &tr, &va, &train_cfg(cfg, w, 4), method.name(), progress)?;
            Ok(single_net(method, net, epochs, base_id, &tr, &va, cfg, t0))
        }
        Method::M4f => {
            if !matches!(base.method(), Method::M2 | Method::M2f) {
                return Err(CalibError::Mismatch(format!("m4f fine-tunes an m2 model, base is {}", base.method())));
            }
            let net = base_net()?;
            let (tr, va) = train_val(data, val, cfg);
            m4f(net, &tr, &va, cfg, base, base_id, t0, progress)
        }
        Method::M1 | Method::M2 => {
            Err(CalibError::Invalid(format!("{} is trained from scratch: use fit", method.name())))
        }
    }
}

fn subset(d: &Dataset, keep: impl Fn(usize) -> bool) -> Dataset {
    Dataset {
        samples: d.samples.iter().enumerate().filter(|(i, _)| keep(*i)).map(|(_, s)| s.clone()).collect(),
        extra_columns: d.extra_columns.clone(),
    }
}

/// M4: M2's shared layers frozen, each branch duplicated into an internal and an external copy,
/// the workspace split by the PSC. S_init and dS are searched on validation data over
/// percentiles of the training S (our geometry's S range differs from the paper's).
#[allow(clippy::too_many_arguments)]
fn m4f(
    base_net: Net,
    tr: &Dataset,
    va: &Dataset,
    cfg: &FitConfig,
    base: &FkModel,
    base_id: Option<String>,
    t0: Instant,
    progress: Progress,
) -> Result<ModelParts> {
    let psc_of = |d: &Dataset| -> Result<Vec<f64>> {
        let mut st = base.state();
        d.samples.iter().map(|s| base.psc(&mut st, &s.theta_deg)).collect()
    };
    let (s_tr, s_va) = (psc_of(tr)?, psc_of(va)?);
    let spread = percentile(&s_tr, 0.9) - percentile(&s_tr, 0.1);
    let frozen = base_net.trunk.len();
    let mut best: Option<(f64, PscSplit, Net, Net, Vec<usize>)> = None;
    let quantiles = [0.3, 0.4, 0.5, 0.6, 0.7];
    let ds_fracs = [0.02, 0.05, 0.1];
    let total = quantiles.len() * ds_fracs.len();
    let mut step = 0;
    for q in quantiles {
        for f in ds_fracs {
            step += 1;
            let s_init = percentile(&s_tr, q);
            let ds = f * spread;
            let inner = subset(tr, |i| s_tr[i] <= s_init + ds);
            let outer = subset(tr, |i| s_tr[i] > s_init - ds);
            if inner.len() < MIN_SAMPLES / 2 || outer.len() < MIN_SAMPLES / 2 {
                continue;
            }
            let va_in = subset(va, |i| s_va[i] <= s_init + ds);
            let va_out = subset(va, |i| s_va[i] > s_init - ds);
            let tc = train_cfg(cfg, W_M2, frozen);
            let mut ni = base_net.clone();
            let mut no = base_net.clone();
            let mut quiet = |_: &str, _: usize, _: usize, _: f64, _: f64| {};
            let (ei, _) =
                train_net(&mut ni, &inner, if va_in.is_empty() { &inner } else { &va_in }, &tc, "m4f", &mut quiet)?;
            let (eo, _) =
                train_net(&mut no, &outer, if va_out.is_empty() { &outer } else { &va_out }, &tc, "m4f", &mut quiet)?;
            // Score: MSE_total on the validation set with inference choosing by S.
            let mse: f64 = va
                .samples
                .iter()
                .zip(&s_va)
                .map(|(s, &sv)| {
                    let p = if sv <= s_init { ni.eval(&s.theta_deg) } else { no.eval(&s.theta_deg) };
                    (0..6).map(|k| (p[k] - s.pose[k]).powi(2)).sum::<f64>() / 6.0
                })
                .sum::<f64>()
                / va.len().max(1) as f64;
            progress("m4f search", step, total, mse, s_init);
            let frac = s_tr.iter().filter(|&&s| s <= s_init).count() as f64 / s_tr.len() as f64;
            if best.as_ref().is_none_or(|b| mse < b.0) {
                best = Some((mse, PscSplit { s_init, ds, internal_fraction: frac }, ni, no, vec![ei, eo]));
            }
        }
    }
    let (_, split, ni, no, epochs) =
        best.ok_or_else(|| CalibError::Data("m4f: too few samples on one side of every PSC split".into()))?;
    // the full validation metrics of the chosen split, as every method records them
    let pred: Vec<[f64; 6]> = va
        .samples
        .iter()
        .zip(&s_va)
        .map(|(s, &sv)| if sv <= split.s_init { ni.eval(&s.theta_deg) } else { no.eval(&s.theta_deg) })
        .collect();
    let validation = serde_json::to_value(evaluate(&pred, &xy(va).1, &Target::paper())).expect("json");
    let mut m = Manifest::new(Method::M4f);
    m.psc = Some(split);
    m.training.epochs = epochs;
    m.training.base = base_id;
    m.validation = Some(validation);
    Ok(ModelParts {
        manifest: finish(m, tr, va, cfg, t0),
        nets: vec![("internal".into(), ni), ("external".into(), no)],
        unit: None,
    })
}
