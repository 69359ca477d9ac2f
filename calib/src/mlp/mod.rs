//! Training of the paper's networks (M1, M2) with Adam on normalised data; the networks and
//! their evaluation are abvs-fk's ([`abvs_fk::net`], re-exported here).
//!
//! A [`Net`] maps raw link angles (deg) to the raw pose `[alpha, beta, gamma (deg), x, y, z
//! (mm)]`. The normalisation is part of the model ([`Net::input_norm`], [`Net::output_norm`]),
//! so callers never see normalised values. Layers are [`Dense`] (f32 weights); the trunk's
//! layers are followed by ReLU (except the trunk's last layer when there are no heads: then it
//! is the linear output); each head branches from the trunk output, has ReLU between its
//! layers and a linear last layer, and the heads' outputs are concatenated in order.
//!
//! "Depth" numbers layers along a path from the input: trunk layers `0..trunk.len()`, then
//! each head's layers continue from `trunk.len()`. Freezing the first `k` layers
//! ([`TrainConfig::frozen_layers`]) freezes by depth, so `k = net.trunk.len()` freezes exactly
//! the shared trunk (what M4 needs), and `k = 4` on a 7-layer M1 or a 4+3 M2 gives the paper's
//! m1f/m2f fine-tuning.
//!
//! Two evaluation paths: [`Net::eval`] (batch 1, stack buffers, AVX2/FMA kernels when the CPU
//! has them; this is the per-frame path) and [`Net::eval_batch`] (GEMM, the same code the
//! training uses). They agree to f32 rounding, not bit for bit.
use crate::{CalibError, Result};
use abvs_fk::batch::{forward, layer_mut, Plan};
pub use abvs_fk::net::*;
use adam::{adam, Moments, B1, B2};
use backprop::{backward, loss, Grads};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use std::time::Instant;

mod adam;
mod backprop;

/// Training hyper-parameters (defaults: the paper's).
#[derive(Debug, Clone)]
pub struct TrainConfig {
    pub lr: f64,
    pub batch: usize,
    pub max_epochs: usize,
    /// Stop after this many epochs without a validation improvement.
    pub patience: usize,
    /// Shuffling seed (initialisation has its own seed in [`Net::m1`]/[`Net::m2`]).
    pub seed: u64,
    /// Per-output loss weights in normalised space; the loss is
    /// `sum_j w_j * MSE_j / sum_j w_j`, so all-ones is the plain MSE and
    /// [`M2_OUTPUT_WEIGHTS`] is `2/3 MSE_rot + 1/3 MSE_trans` (the paper's 2:1).
    pub output_weights: [f64; 6],
    /// Freeze the first k layers by depth: trunk layers first, then the first
    /// `k - trunk.len()` layers of each head. Frozen layers are bit-identical after training.
    pub frozen_layers: usize,
    /// L2 penalty added to the gradient (torch.optim.Adam's `weight_decay`), on all parameters.
    pub weight_decay: f64,
}

impl Default for TrainConfig {
    fn default() -> Self {
        TrainConfig {
            lr: 1e-4,
            batch: 128,
            max_epochs: 1000,
            patience: 100,
            seed: 0,
            output_weights: [1.0; 6],
            frozen_layers: 0,
            weight_decay: 0.0,
        }
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct TrainReport {
    /// Epochs run (1-based numbering in `best_epoch` and `progress`).
    pub epochs: usize,
    /// The epoch whose weights were kept; 0 = the initial weights (validation never improved
    /// on them, e.g. a fine-tuning that only got worse).
    pub best_epoch: usize,
    /// The monitored loss of the kept weights: validation loss, or the epoch's mean training
    /// loss when there is no validation set.
    pub best_val_loss: f64,
    /// Mean minibatch loss of the last epoch.
    pub final_train_loss: f64,
    pub seconds: f64,
    pub stopped_early: bool,
    /// (mean training loss, validation loss or NaN) per epoch.
    pub history: Vec<(f64, f64)>,
}

/// Normalised data as f32 rows.
pub(crate) fn normalise_set<const N: usize>(rows: &[[f64; N]], a: &Affine) -> Vec<f32> {
    let mut out = vec![0f32; rows.len() * N];
    for (d, r) in out.chunks_exact_mut(N).zip(rows) {
        normalise_row(a, r, d);
    }
    out
}

fn check_set(what: &str, x: &[[f64; 3]], y: &[[f64; 6]]) -> Result<()> {
    if x.len() != y.len() {
        return Err(CalibError::Data(format!("{what} set: {} inputs but {} targets", x.len(), y.len())));
    }
    let bad = |i: usize, kind: &str, j: usize, name: &str, v: f64| {
        CalibError::Data(format!("{what} set sample {i}, {kind} column {j} ({name}): value {v} is not finite"))
    };
    for (i, (xr, yr)) in x.iter().zip(y).enumerate() {
        if let Some(j) = xr.iter().position(|v| !v.is_finite()) {
            return Err(bad(i, "input", j, INPUT_COLUMNS[j], xr[j]));
        }
        if let Some(j) = yr.iter().position(|v| !v.is_finite()) {
            return Err(bad(i, "target", j, OUTPUT_COLUMNS[j], yr[j]));
        }
    }
    Ok(())
}

/// Validation inputs and raw targets.
pub type ValSet<'a> = (&'a [[f64; 3]], &'a [[f64; 6]]);

/// Trains `net` in place with Adam on minibatches (see [`TrainConfig`]) and keeps the weights
/// of the best epoch by validation loss (without validation data: by mean training loss).
/// Targets are raw poses; the net's own normalisations are used (fit them with
/// [`Affine::fit`] on the training set before building the net, keep them for fine-tuning).
/// Deterministic for a given seed and net. `progress(epoch, train_loss, val_loss)` is called
/// after each epoch (val_loss NaN without validation data).
///
/// Errors: [`CalibError::Data`] for an empty set, length mismatches, non-finite values (naming
/// sample and column), batch 0; [`CalibError::Invalid`] for a malformed net or config, or a
/// diverged training (the net is then left at its best weights).
pub fn train(
    net: &mut Net,
    x: &[[f64; 3]],
    y: &[[f64; 6]],
    val: Option<ValSet<'_>>,
    cfg: &TrainConfig,
    progress: &mut dyn FnMut(usize, f64, f64),
) -> Result<TrainReport> {
    let start = Instant::now();
    if x.is_empty() {
        return Err(CalibError::Data("empty training set".into()));
    }
    if cfg.batch == 0 {
        return Err(CalibError::Data("batch size 0".into()));
    }
    check_set("training", x, y)?;
    if let Some((vx, vy)) = val {
        check_set("validation", vx, vy)?;
    }
    let val = val.filter(|(vx, _)| !vx.is_empty());
    net.validate().map_err(|e| CalibError::Invalid(format!("net: {e}")))?;
    if net.n_in() != 3 || net.n_out() != 6 {
        return Err(CalibError::Mismatch(format!(
            "training needs a 3 -> 6 net, this one is {} -> {}",
            net.n_in(),
            net.n_out()
        )));
    }
    let lr_ok = cfg.lr.is_finite() && cfg.lr > 0.0;
    let wd_ok = cfg.weight_decay.is_finite() && cfg.weight_decay >= 0.0;
    if !lr_ok || !wd_ok {
        return Err(CalibError::Invalid(format!("learning rate {} / weight decay {}", cfg.lr, cfg.weight_decay)));
    }
    let w = &cfg.output_weights;
    if w.iter().any(|v| !(v.is_finite() && *v >= 0.0)) || w.iter().sum::<f64>() <= 0.0 {
        return Err(CalibError::Invalid(format!("output weights {w:?}")));
    }
    if cfg.frozen_layers >= net.depth() {
        return Err(CalibError::Invalid(format!(
            "{} frozen layers leave nothing to train in a net of depth {}",
            cfg.frozen_layers,
            net.depth()
        )));
    }

    let plan = Plan::new(net);
    let outs = plan.outputs();
    let trainable: Vec<bool> = plan.layers.iter().map(|p| p.depth >= cfg.frozen_layers).collect();
    let wts: [f32; 6] = w.map(|v| v as f32);

    let n = x.len();
    let xn = normalise_set(x, &net.input_norm);
    let yn = normalise_set(y, &net.output_norm);
    let vset = val.map(|(vx, vy)| (normalise_set(vx, &net.input_norm), normalise_set(vy, &net.output_norm), vx.len()));

    let cap = cfg.batch.min(n).max(CHUNK);
    let mut acts = plan.buffers(cap);
    let mut g = Grads::new(&plan, cap);
    let mut mom: Vec<Moments> = plan.layers.iter().map(|p| Moments::zeros(p.n_in, p.n_out)).collect();
    let mut xb = vec![0f32; cap * 3];
    let mut yb = vec![0f32; cap * 6];

    let val_loss = |net: &Net, acts: &mut [Vec<f32>]| -> f64 {
        let Some((vx, vy, nv)) = &vset else {
            return f64::NAN;
        };
        let mut sum = 0.0;
        for start in (0..*nv).step_by(cap) {
            let m = cap.min(nv - start);
            forward(net, &plan, &vx[start * 3..(start + m) * 3], m, acts);
            sum += m as f64 * loss(&plan, &outs, acts, &vy[start * 6..(start + m) * 6], m, &wts, None);
        }
        sum / *nv as f64
    };

    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let mut order: Vec<usize> = (0..n).collect();
    let mut best = net.clone();
    let (mut best_loss, mut best_epoch) = (if vset.is_some() { val_loss(net, &mut acts) } else { f64::INFINITY }, 0);
    let mut history = Vec::new();
    let mut t = 0i32;
    let mut stopped_early = false;
    let wd = cfg.weight_decay as f32;

    for epoch in 1..=cfg.max_epochs {
        order.shuffle(&mut rng);
        let mut sum = 0.0;
        for idx in order.chunks(cfg.batch) {
            let m = idx.len();
            for (k, &i) in idx.iter().enumerate() {
                xb[k * 3..k * 3 + 3].copy_from_slice(&xn[i * 3..i * 3 + 3]);
                yb[k * 6..k * 6 + 6].copy_from_slice(&yn[i * 6..i * 6 + 6]);
            }
            forward(net, &plan, &xb[..m * 3], m, &mut acts);
            sum += m as f64 * loss(&plan, &outs, &acts, &yb[..m * 6], m, &wts, Some(&mut g.da));
            backward(net, &plan, &xb[..m * 3], m, &acts, &mut g, &trainable);
            t += 1;
            let bc1 = 1.0 - (B1 as f64).powi(t);
            let bc2 = 1.0 - (B2 as f64).powi(t);
            let step = (cfg.lr / bc1) as f32;
            let isbc2 = (1.0 / bc2.sqrt()) as f32;
            for (l, p) in plan.layers.iter().enumerate().filter(|(l, _)| trainable[*l]) {
                let d = layer_mut(net, p);
                let mo = &mut mom[l];
                adam(&mut d.w, &g.dw[l], &mut mo.mw, &mut mo.vw, step, isbc2, wd);
                adam(&mut d.b, &g.db[l], &mut mo.mb, &mut mo.vb, step, isbc2, wd);
            }
        }
        let train_loss = sum / n as f64;
        let vl = val_loss(net, &mut acts);
        history.push((train_loss, vl));
        progress(epoch, train_loss, vl);
        let monitored = if vset.is_some() { vl } else { train_loss };
        if !monitored.is_finite() || !train_loss.is_finite() {
            *net = best;
            return Err(CalibError::Invalid(format!(
                "training diverged at epoch {epoch} (loss {train_loss}); lower the learning rate \
                 (the net keeps its best weights, from epoch {best_epoch})"
            )));
        }
        if monitored < best_loss {
            best_loss = monitored;
            best_epoch = epoch;
            best.clone_from(net);
        } else if epoch - best_epoch >= cfg.patience {
            stopped_early = true;
            break;
        }
    }
    *net = best;
    Ok(TrainReport {
        epochs: history.len(),
        best_epoch,
        best_val_loss: best_loss,
        final_train_loss: history.last().map_or(f64::NAN, |h| h.0),
        seconds: start.elapsed().as_secs_f64(),
        stopped_early,
        history,
    })
}
