//! The discrepancy workflow: find where the unit model and the measurements disagree, name the
//! missing physical effects from the library (effects.md), add them, and show the held-out gap
//! shrink; stop when nothing significant is left, and describe what no effect explains.
//!
//! 1. **Start** (`start`): the given model, or, without one, the nominal unit with the
//!    geometric effects every real unit has, fitted in stages (hand-eye first).
//! 2. **Noise floor** (`structure`): second differences of the residual along runs of evenly
//!    spaced samples.
//! 3. **Rounds**: linearise around the fitted model (`design`) and choose jointly which
//!    candidate effects to add (`select`): sets of up to three effects scored by 3-fold
//!    cross-validated chi-square, every member necessary and plausible, outside structure
//!    (ripples, with their harmonics, drifts) competing with library sets under the same
//!    penalty, substitutes reported as ambiguity with the experiment
//!    that would separate them (`separate`). The chosen effects are then fitted for real
//!    (Levenberg-Marquardt on the unit model) and their held-out residual measured by real
//!    cross-validated refits.
//! 4. **Report** (`report`): what was named, with evidence and sizes; parameters stuck at a
//!    plausibility bound with what they are probably absorbing; unexplained structure.
mod design;
mod report;
mod select;
mod separate;
mod start;
mod structure;

pub use report::{explaining_variable, report_markdown, summary_json};
pub use separate::SeparatingPose;
pub use start::KNOWN_GEOMETRIC;
pub use structure::{noise_from_second_differences, Harmonic, Outside};

use crate::error::{CalibError, Result};
use crate::identify::{fit_params, get, residuals, set, FitOptions, Param};
use abvs_eye::dataset::Dataset;
use abvs_eye::unit::{Effect, UnitModel};
use design::Design;
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use select::SelectOptions;
use serde::Serialize;
use std::collections::BTreeMap;

#[derive(Debug, Clone)]
pub struct ExplainOptions {
    pub folds: usize,
    pub max_rounds: usize,
    pub seed: u64,
    /// Effects that may be added (default: every effect a static dataset can reveal).
    pub candidates: Vec<Effect>,
    /// Share of the structured held-out misfit the other members leave that a named effect
    /// must remove.
    pub min_excess_fraction: f64,
    /// LM iterations per cross-validation fit (warm-started, so few are needed).
    pub cv_iterations: usize,
    /// Largest set of effects considered jointly.
    pub max_joint: usize,
    /// The final held-out residual within this factor of the floor counts as explained.
    pub floor_factor: f64,
}

impl Default for ExplainOptions {
    fn default() -> Self {
        ExplainOptions {
            folds: 3,
            max_rounds: 3,
            seed: 0,
            candidates: Effect::ALL.into_iter().filter(|e| e.is_kinematic()).collect(),
            min_excess_fraction: 0.3,
            cv_iterations: 8,
            max_joint: 3,
            floor_factor: 1.2,
        }
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct CandidateScore {
    pub effect: String,
    pub params_added: usize,
    /// Fraction of the held-out chi-square removed alone, after the parameter penalty.
    pub score: f64,
    /// Fraction of the structured (above-noise) held-out misfit removed alone.
    pub excess_fraction: f64,
    /// Named this round.
    pub significant: bool,
    pub note: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct Step {
    pub effect: String,
    /// The form fitted, where the effect has several (the hinge_backlash reading the data
    /// support, one wheel or free heads, a common or per-link scale).
    pub form: Option<String>,
    pub params: BTreeMap<String, f64>,
    pub std_errors: BTreeMap<String, f64>,
    pub score: f64,
    /// Effects named in the same round (the joint decision).
    pub joint_with: Vec<String>,
    pub rms_rot_deg_before: f64,
    pub rms_rot_deg_after: f64,
    pub rms_trans_mm_before: f64,
    pub rms_trans_mm_after: f64,
    /// RMS over the dataset of the rotation the effect contributes (deg), as fitted.
    pub signature_rms_rot_deg: f64,
    pub evidence: String,
    /// Set where the fitted size lies beyond effects.md's plausible range (still named: the
    /// data need it and nothing else explains it).
    pub warning: Option<String>,
    pub candidates: Vec<CandidateScore>,
    #[serde(skip)]
    pub heldout_before: Vec<[f64; 6]>,
    #[serde(skip)]
    pub heldout_after: Vec<[f64; 6]>,
}

/// Candidates the data cannot tell apart.
#[derive(Debug, Clone, Serialize)]
pub struct Ambiguity {
    /// The effects, the better-scoring first (it is the one carried in the model).
    pub effects: Vec<String>,
    pub evidence: String,
    /// Where the alternatives' predictions differ most: the measurements to take next.
    pub separating: Vec<SeparatingPose>,
}

/// A fitted parameter at a plausibility bound: reported with what it is probably absorbing.
#[derive(Debug, Clone, Serialize)]
pub struct AtBound {
    pub param: String,
    pub value: f64,
    pub bound: f64,
    pub absorbing: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct Unexplained {
    pub description: String,
    pub rms_rot_deg: f64,
    /// The ripple behind the description, when it is one (link, cycle count, amplitude, and
    /// its second harmonic where the data need it).
    pub ripple: Option<Harmonic>,
    /// The drift behind the description, when it is one: rotation of the measured orientation
    /// from the first to the last sample (deg).
    pub drift_deg: Option<f64>,
}

#[derive(Debug, Clone)]
pub struct ExplainResult {
    /// Per-sample norm RMS of pure measurement noise (sqrt(3) sigma per axis).
    pub noise_floor_rot_deg: f64,
    pub noise_floor_trans_mm: f64,
    /// How the floor was estimated.
    pub noise_method: String,
    /// The known model's effects and how the start was reached.
    pub known_model: Vec<String>,
    pub default_start: bool,
    pub start_notes: Vec<String>,
    pub initial_rms: (f64, f64),
    pub steps: Vec<Step>,
    pub ambiguous: Vec<Ambiguity>,
    pub at_bounds: Vec<AtBound>,
    pub unexplained: Vec<Unexplained>,
    pub unit: UnitModel,
    /// Held-out residuals of the final model.
    pub final_heldout: Vec<[f64; 6]>,
    pub final_rms: (f64, f64),
    /// Physical parameters the data could not separate in the final model.
    pub held: Vec<String>,
    /// Candidate scores of the last round.
    pub final_candidates: Vec<CandidateScore>,
}

/// The observable size of an effect: the Euclidean norm of its parameter vector (natural
/// units), without the components no pose relative to home can show. A zero offset common to
/// all three links is a pure roll of the whole mechanism (equal link motion is pure roll), which
/// cancels in `T_C(home)^-1 T_C(theta)`; the same holds for a common platform-axis azimuth error.
/// Those common modes are removed before taking the norm. Platform-axis elevation errors are not
/// separable from distal link (d2) errors, so the size of platform_axis_error is its
/// differential azimuth part.
pub fn effect_size(unit: &UnitModel, e: Effect) -> f64 {
    let p = unit.params(e);
    let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
    let demean = |v: &[f64]| {
        let m = v.iter().sum::<f64>() / v.len() as f64;
        v.iter().map(|x| x - m).collect::<Vec<f64>>()
    };
    match e {
        Effect::EncoderZeroOffset => norm(&demean(&p)),
        Effect::PlatformAxisError => norm(&demean(&p[..3])),
        _ => norm(&p),
    }
}

/// RMS over the dataset of the rotation (deg) and translation (mm) effect `e` contributes to
/// `unit`'s predictions: the model with it against the model without it. A parameter-free
/// size, comparable across parameterisations (e.g. with an independent simulator's truth).
pub fn signature_rms(unit: &UnitModel, e: Effect, data: &Dataset) -> Result<(f64, f64)> {
    let mut without = unit.clone();
    without.set_enabled(e, false);
    let (a, b) = (unit.compile()?.predict_dataset(data)?, without.compile()?.predict_dataset(data)?);
    let d: Vec<[f64; 6]> = a.iter().zip(&b).map(|(x, y)| crate::identify::residual6(y, x)).collect();
    Ok(crate::identify::rms(&d))
}

fn rms_norm(res: &[[f64; 6]]) -> (f64, f64) {
    crate::identify::rms(res)
}

struct Ctx<'a> {
    data: &'a Dataset,
    folds: Vec<Vec<bool>>,
    sigma: (f64, f64),
    iters: usize,
}

impl Ctx<'_> {
    fn opts(&self, mask: Option<Vec<bool>>, fit_all: bool, iters: usize) -> FitOptions {
        FitOptions {
            sigma_rot_deg: self.sigma.0,
            sigma_trans_mm: self.sigma.1,
            max_iter: iters,
            fit_all,
            mask,
            ..FitOptions::default()
        }
    }

    /// Held-out residual of every sample (each from the fold that left it out), by real
    /// refits of the model's free parameters.
    fn cv(&self, start: &UnitModel, free: &[Param]) -> Result<Vec<[f64; 6]>> {
        let n = self.data.len();
        let mut out = vec![[0.0; 6]; n];
        for test in &self.folds {
            let train: Vec<bool> = test.iter().map(|t| !t).collect();
            let fit = fit_params(start, free, self.data, &self.opts(Some(train), true, self.iters))?;
            let r = residuals(&fit.unit, self.data)?;
            for i in 0..n {
                if test[i] {
                    out[i] = r[i];
                }
            }
        }
        Ok(out)
    }
}

/// `unit` with the parameters moved by `delta` (their effects switched on), kept inside the
/// hard limits.
fn apply(unit: &UnitModel, params: &[Param], delta: &[f64]) -> UnitModel {
    let mut u = unit.clone();
    for p in params {
        u.set_enabled(p.effect, true);
    }
    let x: Vec<f64> = get(&u, params).iter().zip(delta).map(|(v, d)| v + d).collect();
    set(&mut u, params, &x);
    u
}

/// A warning where the fitted effect lies beyond the top of effects.md's typical range: the
/// data need it and nothing else explains it, so it is named, but a unit this far off is worth
/// a look (or something outside the library hides behind it). Eccentricity compares each
/// head's amplitude (one wheel shows every head the same).
fn beyond_range(unit: &UnitModel, e: Effect) -> Option<String> {
    let p = unit.params(e);
    let ps = crate::identify::params_of(&[e]);
    let ratio = match e {
        Effect::CodeWheelEccentricity => (0..3).map(|i| p[i].hypot(p[i + 3])).fold(0.0, f64::max) / ps[0].range_top(),
        _ => p.iter().zip(&ps).map(|(v, q)| v.abs() / q.range_top()).fold(0.0, f64::max),
    };
    (ratio > 1.0).then(|| format!("fitted size {ratio:.1}x the top of effects.md's range for {e}"))
}

/// Checks what the workflow cannot work with and says why.
fn check_data(data: &Dataset) -> Result<()> {
    if data.len() < 30 {
        return Err(CalibError::Data(format!("{} samples: the workflow needs at least 30", data.len())));
    }
    if let Some(s) = data.samples.iter().find(|s| !(s.theta_deg.iter().chain(&s.pose).all(|v| v.is_finite()))) {
        return Err(CalibError::Data(format!("sample seq {}: a value is not a finite number", s.seq)));
    }
    Ok(())
}

/// Runs the workflow. `progress(message)` reports each stage.
pub fn explain(
    start: &UnitModel,
    data: &Dataset,
    opts: &ExplainOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<ExplainResult> {
    check_data(data)?;
    let n = data.len();
    let mut idx: Vec<usize> = (0..n).collect();
    idx.shuffle(&mut ChaCha8Rng::seed_from_u64(opts.seed));
    let k = opts.folds.clamp(2, 10);
    let folds: Vec<Vec<bool>> = (0..k)
        .map(|f| {
            let mut m = vec![false; n];
            for (j, &i) in idx.iter().enumerate() {
                if j % k == f {
                    m[i] = true;
                }
            }
            m
        })
        .collect();
    let mut ctx = Ctx { data, folds, sigma: (0.01, 0.05), iters: opts.cv_iterations };

    // Round 0: the known model, fitted in stages.
    let st = start::fit_start(start, data, ctx.sigma, progress)?;
    let mut unit = st.unit.clone();
    let mut free = st.free.clone();

    // Noise floor from the high-frequency part of the residual.
    let r0 = residuals(&unit, data)?;
    let (noise_method, floor_known) = match noise_from_second_differences(data, &r0) {
        Some((a, b, m)) => {
            ctx.sigma = (a, b);
            (format!("second differences of the residual along {m} runs of consecutive evenly spaced samples (robust MAD)"), true)
        }
        None => {
            // No runs to measure it: the known model's own scatter bounds it from above.
            let (rr, rt) = rms_norm(&r0);
            ctx.sigma = ((rr / 3f64.sqrt()).max(1e-6), (rt / 3f64.sqrt()).max(1e-6));
            (
                "too few runs of evenly spaced samples: taken as the known model's residual (an upper bound)"
                    .to_string(),
                false,
            )
        }
    };

    progress("cross-validating the known model");
    let mut held_out = ctx.cv(&unit, &free)?;
    let initial_rms = rms_norm(&held_out);
    let rows = 6 * n;
    let sel_opts = SelectOptions {
        penalty: (rows as f64).ln(),
        floor: rows as f64,
        min_share: opts.min_excess_fraction,
        max_joint: opts.max_joint.max(1),
        ident_ratio: 0.3,
        ambiguity_margin: 0.005,
    };
    let mut steps: Vec<Step> = vec![];
    let mut ambiguous: Vec<Ambiguity> = vec![];
    let mut final_candidates = vec![];
    let mut last_outside = None;
    let mut last_design: Option<(Design, Vec<select::Cand>)> = None;
    for round in 0..opts.max_rounds.max(1) {
        let cands: Vec<Effect> =
            opts.candidates.iter().copied().filter(|c| c.is_kinematic() && !unit.is_enabled(*c)).collect();
        progress(&format!("round {}: linearising {} candidates and the ripples", round + 1, cands.len()));
        let design = Design::build(&unit, &free, &cands, data, &ctx.folds, ctx.sigma)?;
        progress(&format!("round {}: scoring sets of up to {} effects", round + 1, sel_opts.max_joint));
        let choice = select::choose(&design, &sel_opts);
        last_outside = choice.outside;
        final_candidates = choice.table.clone();
        if choice.named.is_empty() {
            last_design = Some((design, choice.candidates));
            break;
        }
        let joint: Vec<String> = choice.named.iter().map(|m| m.effect.name().to_string()).collect();
        progress(&format!(
            "round {}: chose {}",
            round + 1,
            choice
                .named
                .iter()
                .map(|m| format!(
                    "{} (alternatives {:?})",
                    m.effect,
                    m.alternatives.iter().map(|a| a.0.name()).collect::<Vec<_>>()
                ))
                .collect::<Vec<_>>()
                .join(", ")
        ));
        for m in &choice.named {
            let e = m.effect;
            progress(&format!("round {}: fitting {e}", round + 1));
            let mut trial = unit.clone();
            trial.set_params(e, &vec![0.0; e.param_names().len()])?;
            trial.set_enabled(e, true);
            let mut f_new = free.clone();
            f_new.extend(m.params.iter().copied());
            let full = match fit_params(&trial, &f_new, data, &ctx.opts(None, true, 40)) {
                Ok(f) => f,
                Err(err) => {
                    final_candidates.iter_mut().filter(|c| c.effect == e.name()).for_each(|c| {
                        c.significant = false;
                        c.note = format!("chosen, but the nonlinear fit failed: {err}");
                    });
                    continue;
                }
            };
            progress(&format!("round {}: cross-validating with {e}", round + 1));
            let cv_new = ctx.cv(&full.unit, &f_new)?;
            let (before, after) = (rms_norm(&held_out), rms_norm(&cv_new));
            if m.alternatives.is_empty() {
                let mut params = BTreeMap::new();
                let mut ses = BTreeMap::new();
                for (p, se) in full.free.iter().zip(full.std_error.iter().chain(std::iter::repeat(&f64::NAN))) {
                    if p.effect == e {
                        params.insert(p.local_name(), get(&full.unit, &[*p])[0]);
                        ses.insert(p.local_name(), *se);
                    }
                }
                // A tied form also shows the effect's own parameters it sets.
                if m.params.iter().any(|p| p.tie.is_some()) {
                    for (n, v) in e.param_names().into_iter().zip(full.unit.params(e)) {
                        params.insert(n, v);
                    }
                }
                let sig = signature_rms(&full.unit, e, data).map(|s| s.0).unwrap_or(f64::NAN);
                steps.push(Step {
                    effect: e.name().into(),
                    form: m.form.clone(),
                    params,
                    std_errors: ses,
                    score: m.marginal / choice.chi_base.max(1e-300),
                    joint_with: joint.iter().filter(|j| *j != e.name()).cloned().collect(),
                    rms_rot_deg_before: before.0,
                    rms_rot_deg_after: after.0,
                    rms_trans_mm_before: before.1,
                    rms_trans_mm_after: after.1,
                    signature_rms_rot_deg: sig,
                    evidence: report::evidence(e, data, &held_out, &cv_new),
                    warning: beyond_range(&full.unit, e),
                    candidates: choice.table.clone(),
                    heldout_before: held_out.clone(),
                    heldout_after: cv_new.clone(),
                });
            } else {
                ambiguous.push(ambiguity(&design, &choice, m, &unit, &free, before.0, after.0));
            }
            unit = full.unit;
            free = full.free;
            held_out = cv_new;
        }
    }

    let final_rms = rms_norm(&held_out);
    let (nf_r, nf_t) = if floor_known { (3f64.sqrt() * ctx.sigma.0, 3f64.sqrt() * ctx.sigma.1) } else { final_rms };
    // What is left: parameters at a bound and structure no library effect explains.
    let mut at_bounds = vec![];
    let design = match last_design {
        Some(d) => Some(d),
        None => {
            let cands: Vec<Effect> =
                opts.candidates.iter().copied().filter(|c| c.is_kinematic() && !unit.is_enabled(*c)).collect();
            Design::build(&unit, &free, &cands, data, &ctx.folds, ctx.sigma).ok().map(|d| {
                let c = select::candidates(&d, &sel_opts).into_iter().filter_map(|c| c.1).collect();
                (d, c)
            })
        }
    };
    for (k, p) in free.iter().enumerate() {
        let v = get(&unit, &[*p])[0];
        let bound = if v.abs() >= 0.98 * p.hard_limit() { p.hard_limit() } else { p.plausible_max() };
        if v.abs() >= 0.98 * bound {
            let absorbing = design.as_ref().map(|(d, c)| select::absorbing(d, k, c)).unwrap_or_default();
            at_bounds.push(AtBound { param: p.name(), value: v, bound, absorbing });
        }
    }
    let mut unexplained = vec![];
    // Structure left: above the floor, or outside structure that still removes significant
    // held-out chi-square (a small effect outside the library can hide under the floor factor).
    if final_rms.0 > opts.floor_factor * nf_r || final_rms.1 > opts.floor_factor * nf_t || last_outside.is_some() {
        let ripple = match last_outside {
            Some(Outside::Ripple(h)) if h.amplitude_deg > 0.5 * ctx.sigma.0 => Some(h),
            _ => None,
        };
        let drift_deg = match last_outside {
            Some(Outside::Drift { end_deg, .. }) if end_deg > ctx.sigma.0 => Some(end_deg),
            _ => None,
        };
        unexplained.push(Unexplained {
            description: structure::describe(data, &held_out, last_outside, ctx.sigma.0),
            rms_rot_deg: final_rms.0,
            ripple,
            drift_deg,
        });
    }
    let held = fit_params(&unit, &free, data, &FitOptions { max_iter: 0, ..ctx.opts(None, false, 0) })
        .map(|f| f.held.iter().map(|h| h.name.clone()).collect())
        .unwrap_or_default();
    Ok(ExplainResult {
        noise_floor_rot_deg: nf_r,
        noise_floor_trans_mm: nf_t,
        noise_method,
        known_model: st.known.iter().map(|e| e.name().to_string()).collect(),
        default_start: st.default_start,
        start_notes: st.notes,
        initial_rms,
        steps,
        ambiguous,
        at_bounds,
        unexplained,
        unit,
        final_heldout: held_out,
        final_rms,
        held,
        final_candidates,
    })
}

/// An ambiguous member: the evidence and where the alternatives' models disagree most.
fn ambiguity(
    design: &Design,
    choice: &select::Choice,
    m: &select::Named,
    unit: &UnitModel,
    free: &[Param],
    before: f64,
    after: f64,
) -> Ambiguity {
    let base = design.base();
    // The two alternative models, fitted (linearised) to the same data.
    let model_with = |e: Effect| -> Option<UnitModel> {
        let c = choice.candidates.iter().find(|c| c.effect == e)?;
        let cols: Vec<usize> = base.iter().chain(&c.cols).copied().collect();
        let (x, _) = design.fit(&cols);
        let params: Vec<Param> = free.iter().chain(&c.params).copied().collect();
        let values: Vec<f64> = x[..base.len()].iter().copied().chain(c.values(&x[base.len()..])).collect();
        let mut u = unit.clone();
        u.set_params(e, &vec![0.0; e.param_names().len()]).ok()?;
        Some(apply(&u, &params, &values))
    };
    let mut effects = vec![m.effect.name().to_string()];
    effects.extend(m.alternatives.iter().map(|a| a.0.name().to_string()));
    let alt = m.alternatives.first().map(|a| a.0);
    let separating = match (model_with(m.effect), alt.and_then(model_with)) {
        (Some(a), Some(b)) => separate::separating_poses(&a, &b, 5),
        _ => vec![],
    };
    let evidence = format!(
        "{} removes {:.0} of held-out chi-square given the rest; {} (held-out rotation {:.4} -> {:.4} deg with the first in the model)",
        m.effect,
        m.marginal,
        m.alternatives.iter().map(|a| format!("{} removes {:.0} in its place", a.0, a.1)).collect::<Vec<_>>().join(", "),
        before,
        after
    );
    Ambiguity { effects, evidence, separating }
}
