//! The discrepancy workflow: find where the unit model and the measurements disagree, name the
//! missing physical effect from the library (effects.md), add it, and show the held-out gap
//! shrink; stop when nothing significant is left, and describe what no effect explains.
//!
//! Rounds: (1) fit the current model (its enabled effects, identifiable parameters only);
//! (2) K-fold cross-validation gives every sample a held-out residual; (3) every effect not yet
//! in the model is tried as an extension, scored by the held-out chi-square it removes (noise
//! units), penalised by `k ln N` for its k parameters, and checked for physical plausibility of
//! the fitted size and for explaining a real share of the structured misfit; (4) the best
//! significant one is added. Predictions always run over the whole dataset in acquisition order
//! (motion history), only the cost is restricted to the training folds.
use crate::error::{CalibError, Result};
use crate::identify::{fit_params, params_of, residuals, weighted_jacobian, FitOptions, Param};
use abvs_eye::dataset::Dataset;
use abvs_eye::unit::{Effect, MotionHistory, UnitModel};
use nalgebra::DVector;
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use std::collections::BTreeMap;

#[derive(Debug, Clone)]
pub struct ExplainOptions {
    pub folds: usize,
    pub max_rounds: usize,
    pub seed: u64,
    /// Effects that may be added (default: every effect a static dataset can reveal).
    pub candidates: Vec<Effect>,
    /// Share of the structured held-out misfit (above the noise) a winner must remove.
    pub min_excess_fraction: f64,
    /// LM iterations per cross-validation fit (warm-started, so few are needed).
    pub cv_iterations: usize,
}

impl Default for ExplainOptions {
    fn default() -> Self {
        ExplainOptions {
            folds: 3,
            max_rounds: 8,
            seed: 0,
            candidates: Effect::ALL.into_iter().filter(|e| e.is_kinematic()).collect(),
            min_excess_fraction: 0.3,
            cv_iterations: 8,
        }
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct CandidateScore {
    pub effect: String,
    pub params_added: usize,
    /// Fraction of the held-out chi-square removed, after the parameter penalty.
    pub score: f64,
    /// Fraction of the structured (above-noise) held-out misfit removed.
    pub excess_fraction: f64,
    pub significant: bool,
    pub note: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct Step {
    pub effect: String,
    pub params: BTreeMap<String, f64>,
    pub std_errors: BTreeMap<String, f64>,
    pub score: f64,
    pub rms_rot_deg_before: f64,
    pub rms_rot_deg_after: f64,
    pub rms_trans_mm_before: f64,
    pub rms_trans_mm_after: f64,
    pub evidence: String,
    pub candidates: Vec<CandidateScore>,
    #[serde(skip)]
    pub heldout_before: Vec<[f64; 6]>,
    #[serde(skip)]
    pub heldout_after: Vec<[f64; 6]>,
}

#[derive(Debug, Clone, Serialize)]
pub struct Unexplained {
    pub description: String,
    pub rms_rot_deg: f64,
}

#[derive(Debug, Clone)]
pub struct ExplainResult {
    /// Per-sample norm RMS of pure measurement noise (sqrt(3) sigma per axis).
    pub noise_floor_rot_deg: f64,
    pub noise_floor_trans_mm: f64,
    /// How the floor was estimated.
    pub noise_method: String,
    pub initial_rms: (f64, f64),
    pub steps: Vec<Step>,
    pub unexplained: Vec<Unexplained>,
    pub unit: UnitModel,
    /// Held-out residuals of the final model.
    pub final_heldout: Vec<[f64; 6]>,
    /// Physical parameters the data could not separate in the final model.
    pub held: Vec<String>,
    /// Candidate scores of the last round, where none was significant.
    pub final_candidates: Vec<CandidateScore>,
}

/// The observable size of an effect: the Euclidean norm of its parameter vector (natural
/// units), without the components no pose relative to home can show. A zero offset common to
/// all three links is a pure roll of the whole mechanism (equal link motion is pure roll), which
/// cancels in `T_C(home)^-1 T_C(theta)`; the same holds for a common platform-axis azimuth error.
/// Those common modes are removed before taking the norm. Platform-axis elevation errors are not
/// separable from distal link (d2) errors (the identifiability check holds them when both are in
/// the model), so the size of platform_axis_error is its differential azimuth part.
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

/// Per-axis noise sigma (rot deg, trans mm) from the high-frequency part of the residual:
/// second differences along runs of consecutive, evenly spaced samples cancel the smooth
/// systematic part; a robust (MAD) scale resists the odd jump (e.g. a backlash reversal).
pub fn noise_from_second_differences(data: &Dataset, res: &[[f64; 6]]) -> Option<(f64, f64, usize)> {
    let s = &data.samples;
    let mut d2: [Vec<f64>; 2] = [vec![], vec![]];
    for i in 1..s.len().saturating_sub(1) {
        let (a, b, c) = (&s[i - 1], &s[i], &s[i + 1]);
        if b.seq != a.seq + 1 || c.seq != b.seq + 1 {
            continue;
        }
        // Evenly spaced and close: the middle sample is the midpoint in link angles.
        let ok = (0..3).all(|k| {
            let step = (c.theta_deg[k] - a.theta_deg[k]).abs();
            (a.theta_deg[k] + c.theta_deg[k] - 2.0 * b.theta_deg[k]).abs() < 0.2 * step.max(0.5) && step < 12.0
        });
        if !ok {
            continue;
        }
        for k in 0..6 {
            d2[k / 3].push(res[i - 1][k] - 2.0 * res[i][k] + res[i + 1][k]);
        }
    }
    if d2[0].len() < 90 {
        return None;
    }
    let mad_sigma = |v: &mut Vec<f64>| {
        v.sort_by(|a, b| a.total_cmp(b));
        let med = v[v.len() / 2];
        let mut dev: Vec<f64> = v.iter().map(|x| (x - med).abs()).collect();
        dev.sort_by(|a, b| a.total_cmp(b));
        1.4826 * dev[dev.len() / 2] / 6f64.sqrt()
    };
    let n = d2[0].len() / 3;
    Some((mad_sigma(&mut d2[0]), mad_sigma(&mut d2[1]), n))
}

fn chi2(res: &[[f64; 6]], sigma: (f64, f64)) -> f64 {
    res.iter().map(|r| (0..6).map(|k| (r[k] / if k < 3 { sigma.0 } else { sigma.1 }).powi(2)).sum::<f64>()).sum()
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

    /// Held-out residual of every sample (each from the fold that left it out).
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

    /// The identifiable subset of `free` on the whole dataset (one Jacobian).
    fn identifiable(&self, start: &UnitModel, free: &[Param]) -> Result<(Vec<Param>, Vec<String>)> {
        let fit = fit_params(start, free, self.data, &FitOptions { max_iter: 0, ..self.opts(None, false, 0) })?;
        Ok((fit.free, fit.held.iter().map(|h| h.name.clone()).collect()))
    }
}

/// A significant candidate's fit: the extended unit, its free parameters, held-out residuals.
type Fitted = (UnitModel, Vec<Param>, Vec<[f64; 6]>);

/// Runs the workflow. `progress(message)` reports each fit.
pub fn explain(
    start: &UnitModel,
    data: &Dataset,
    opts: &ExplainOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<ExplainResult> {
    if data.len() < 30 {
        return Err(CalibError::Data(format!("{} samples: the workflow needs at least 30", data.len())));
    }
    let n = data.len();
    let mut idx: Vec<usize> = (0..n).collect();
    idx.shuffle(&mut ChaCha8Rng::seed_from_u64(opts.seed));
    let k = opts.folds.max(2);
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

    // Round 0: the starting model's own effects, fitted.
    let mut unit = start.clone();
    let kin: Vec<Effect> = unit.enabled_effects().into_iter().filter(|e| e.is_kinematic()).collect();
    progress(&format!("fitting the starting model ({} effects)", kin.len()));
    let (mut free, _) = ctx.identifiable(&unit, &params_of(&kin))?;
    unit = fit_params(&unit, &free, data, &ctx.opts(None, true, 40))?.unit;

    // Noise floor from the high-frequency part of the residual.
    let r0 = residuals(&unit, data)?;
    let (noise_method, sig) = match noise_from_second_differences(data, &r0) {
        Some((a, b, m)) => (
            format!(
                "second differences of the residual along {m} runs of consecutive evenly spaced samples (robust MAD)"
            ),
            (a, b),
        ),
        None => (
            "no runs of evenly spaced samples: taken as the rms of the final held-out residual (an upper bound)"
                .to_string(),
            (f64::NAN, f64::NAN),
        ),
    };
    if sig.0.is_finite() {
        ctx.sigma = sig;
    }

    let mut held_out = ctx.cv(&unit, &free)?;
    let initial_rms = rms_norm(&held_out);
    let mut steps = Vec::new();
    let ln_n = (6.0 * n as f64).ln();
    let mut ripple = None;
    for round in 0..opts.max_rounds {
        let chi0 = chi2(&held_out, ctx.sigma);
        // The yardstick: the best ripple no library effect describes. A named effect must
        // explain more than it, or the misfit is not that effect's.
        progress(&format!("round {}: scanning link-angle ripples", round + 1));
        ripple = harmonic_scan(&unit, &free, data, ctx.sigma)?.into_iter().next();
        let generic = ripple.map(|h| h.drop).unwrap_or(0.0);
        let floor = 6.0 * n as f64;
        let mut scored: Vec<(CandidateScore, Option<Fitted>)> = vec![];
        for &c in &opts.candidates {
            if unit.is_enabled(c) || !c.is_kinematic() {
                continue;
            }
            progress(&format!("round {}: trying {}", round + 1, c.name()));
            let mut trial = unit.clone();
            trial.set_enabled(c, true);
            let mut all = free.clone();
            all.extend(params_of(&[c]));
            let (f_c, _) = ctx.identifiable(&trial, &all)?;
            let added = f_c.iter().filter(|p| p.effect == c).count();
            if added == 0 {
                scored.push((
                    CandidateScore {
                        effect: c.name().into(),
                        params_added: 0,
                        score: 0.0,
                        excess_fraction: 0.0,
                        significant: false,
                        note: "not identifiable from these data".into(),
                    },
                    None,
                ));
                continue;
            }
            let cv_c = match ctx.cv(&trial, &f_c) {
                Ok(r) => r,
                Err(e) => {
                    scored.push((
                        CandidateScore {
                            effect: c.name().into(),
                            params_added: added,
                            score: 0.0,
                            excess_fraction: 0.0,
                            significant: false,
                            note: format!("fit failed: {e}"),
                        },
                        None,
                    ));
                    continue;
                }
            };
            let chi_c = chi2(&cv_c, ctx.sigma);
            let penalty = added as f64 * ln_n;
            let drop = chi0 - chi_c;
            let score = (drop - penalty) / chi0;
            let excess = if chi0 > floor { drop / (chi0 - floor) } else { 0.0 };
            let mut note = String::new();
            let mut significant = drop > penalty && excess >= opts.min_excess_fraction && drop > generic;
            let mut fitted = None;
            if significant {
                let full = fit_params(&trial, &f_c, data, &ctx.opts(None, true, 40))?;
                let implausible: Vec<String> = f_c
                    .iter()
                    .filter(|p| p.effect == c)
                    .filter(|p| full.unit.params(c)[p.index].abs() > p.plausible_max())
                    .map(|p| p.name())
                    .collect();
                if !implausible.is_empty() {
                    significant = false;
                    note = format!("fitted size implausible for this effect: {}", implausible.join(", "));
                } else {
                    fitted = Some((full.unit, f_c.clone(), cv_c));
                }
            } else if drop <= penalty {
                note = "explains less than its parameters' penalty".into();
            } else if drop <= generic {
                let h = ripple.expect("generic > 0 only with a ripple");
                note = format!("a {}-cycle ripple of theta{} explains more", h.cycles, h.link + 1);
            } else {
                note = format!("explains only {:.0}% of the structured misfit", 100.0 * excess);
            }
            scored.push((
                CandidateScore {
                    effect: c.name().into(),
                    params_added: added,
                    score,
                    excess_fraction: excess,
                    significant,
                    note,
                },
                fitted,
            ));
        }
        scored.sort_by(|a, b| b.0.score.total_cmp(&a.0.score));
        let candidates: Vec<CandidateScore> = scored.iter().map(|s| s.0.clone()).collect();
        let Some(best) = scored.into_iter().find(|s| s.0.significant) else {
            steps.push(Step::none(candidates, &held_out));
            break;
        };
        let (cs, Some((new_unit, new_free, cv_new))) = best else {
            unreachable!("significant candidates carry their fit")
        };
        let e = Effect::from_name(&cs.effect)?;
        let full = fit_params(&new_unit, &new_free, data, &ctx.opts(None, true, 10))?;
        let names = e.param_names();
        let mut params = BTreeMap::new();
        let mut ses = BTreeMap::new();
        for (p, se) in full.free.iter().zip(&full.std_error) {
            if p.effect == e {
                params.insert(names[p.index].clone(), full.unit.params(e)[p.index]);
                ses.insert(names[p.index].clone(), *se);
            }
        }
        let (before, after) = (rms_norm(&held_out), rms_norm(&cv_new));
        let evidence = evidence(e, data, &held_out, &cv_new);
        steps.push(Step {
            effect: cs.effect.clone(),
            params,
            std_errors: ses,
            score: cs.score,
            rms_rot_deg_before: before.0,
            rms_rot_deg_after: after.0,
            rms_trans_mm_before: before.1,
            rms_trans_mm_after: after.1,
            evidence,
            candidates,
            heldout_before: held_out.clone(),
            heldout_after: cv_new.clone(),
        });
        unit = full.unit;
        free = new_free;
        held_out = cv_new;
    }
    // The steps list holds only named effects; the last "none" round's candidate table is kept
    // for the report through `Step::none`, then removed here.
    let final_candidates =
        steps.last().filter(|s| s.effect.is_empty()).map(|s| s.candidates.clone()).unwrap_or_default();
    steps.retain(|s| !s.effect.is_empty());

    let fin = rms_norm(&held_out);
    let (nf_r, nf_t) = if sig.0.is_finite() { (3f64.sqrt() * sig.0, 3f64.sqrt() * sig.1) } else { fin };
    let mut unexplained = vec![];
    if fin.0 > 1.5 * nf_r || fin.1 > 1.5 * nf_t {
        unexplained.push(describe_structure(data, &held_out, ripple, ctx.sigma));
    }
    let (_, held) = ctx.identifiable(&unit, &free)?;
    Ok(ExplainResult {
        noise_floor_rot_deg: nf_r,
        noise_floor_trans_mm: nf_t,
        noise_method,
        initial_rms,
        steps,
        unexplained,
        unit,
        final_heldout: held_out,
        held,
        final_candidates,
    })
}

impl Step {
    fn none(candidates: Vec<CandidateScore>, held: &[[f64; 6]]) -> Step {
        let r = rms_norm(held);
        Step {
            effect: String::new(),
            params: BTreeMap::new(),
            std_errors: BTreeMap::new(),
            score: 0.0,
            rms_rot_deg_before: r.0,
            rms_rot_deg_after: r.0,
            rms_trans_mm_before: r.1,
            rms_trans_mm_after: r.1,
            evidence: String::new(),
            candidates,
            heldout_before: vec![],
            heldout_after: vec![],
        }
    }
}

/// The variable that shows an effect best, for evidence and plots.
pub fn explaining_variable(e: Effect) -> &'static str {
    match e {
        Effect::HingeBacklash => "direction of approach",
        Effect::CodeWheelEccentricity => "link angle (once per revolution)",
        Effect::EncoderScale | Effect::EncoderZeroOffset => "link angle",
        Effect::GravitySag => "gravity direction in the platform frame",
        _ => "workspace position (alpha x gamma)",
    }
}

fn evidence(e: Effect, data: &Dataset, before: &[[f64; 6]], after: &[[f64; 6]]) -> String {
    let rot = |r: &[f64; 6]| (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
    match e {
        Effect::HingeBacklash => {
            // Mean rotation residual for samples approached from + vs - on each link.
            let mut hist = MotionHistory::new();
            let mut txt = vec![];
            let dirs: Vec<[f64; 3]> = data.samples.iter().map(|s| hist.update(&s.theta_deg)).collect();
            for l in 0..3 {
                let mean = |sign: f64, res: &[[f64; 6]]| {
                    let v: Vec<f64> =
                        dirs.iter().zip(res).filter(|(d, _)| d[l] == sign).map(|(_, r)| r[0] + r[1] + r[2]).collect();
                    v.iter().sum::<f64>() / v.len().max(1) as f64
                };
                txt.push(format!(
                    "link {}: mean residual + vs - approach {:+.4} / {:+.4} deg before, {:+.4} / {:+.4} after",
                    l + 1,
                    mean(1.0, before),
                    mean(-1.0, before),
                    mean(1.0, after),
                    mean(-1.0, after)
                ));
            }
            format!("residual depends on the direction of approach ({})", txt.join("; "))
        }
        Effect::CodeWheelEccentricity | Effect::EncoderScale | Effect::EncoderZeroOffset => {
            let (b, a) = (periodic(data, before, 1), periodic(data, after, 1));
            format!("residual vs link angle: once-per-revolution component {:.4} deg before, {:.4} deg after", b.0, a.0)
        }
        _ => {
            let (b, a): (f64, f64) =
                (before.iter().map(rot).fold(0.0, f64::max), after.iter().map(rot).fold(0.0, f64::max));
            format!(
                "structured residual over the {}: max held-out rotation residual {:.4} deg before, {:.4} deg after",
                explaining_variable(e),
                b,
                a
            )
        }
    }
}

/// Best sinusoid with `cycles` per revolution of one link angle, fitted to the rotation
/// residual: (amplitude deg, link index, residual sum of squares it removes). Over the ~100 deg
/// a link travels, neighbouring harmonics are far from orthogonal, so candidates are compared by
/// the variance they remove, not by their (then inflated) amplitudes.
fn periodic_fit(data: &Dataset, res: &[[f64; 6]], cycles: usize) -> (f64, usize, f64) {
    let mut best = (0.0, 0, 0.0);
    for l in 0..3 {
        let (mut amp2, mut removed) = (0.0, 0.0);
        for ax in 0..3 {
            let (mut ss, mut sc, mut cc, mut ys, mut yc) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for (s, r) in data.samples.iter().zip(res) {
                let t = (cycles as f64) * s.theta_deg[l].to_radians();
                let (si, co) = t.sin_cos();
                ss += si * si;
                sc += si * co;
                cc += co * co;
                ys += r[ax] * si;
                yc += r[ax] * co;
            }
            let det = ss * cc - sc * sc;
            if det.abs() < 1e-9 * (ss * cc).max(1e-300) {
                continue;
            }
            let a = (ys * cc - yc * sc) / det;
            let b = (yc * ss - ys * sc) / det;
            amp2 += a * a + b * b;
            removed += a * ys + b * yc;
        }
        if removed > best.2 {
            best = (amp2.sqrt(), l, removed);
        }
    }
    best
}

fn periodic(data: &Dataset, res: &[[f64; 6]], cycles: usize) -> (f64, usize) {
    let (a, l, _) = periodic_fit(data, res, cycles);
    (a, l)
}

/// A periodic link-angle error that is not a library effect, fitted jointly with the model's
/// free parameters (linearised): the yardstick a named effect must beat.
#[derive(Debug, Clone, Copy)]
pub struct Harmonic {
    pub link: usize,
    pub cycles: usize,
    /// Chi-square (noise units) it removes beyond what the model's own parameters can.
    pub drop: f64,
    /// Link-angle amplitude (deg).
    pub amplitude_deg: f64,
}

/// Scans ripples `a sin(k theta_i) + b cos(k theta_i)` on each link's angle, k = 2..12 (k = 1 is
/// the code wheel's eccentricity), each fitted together with the model's free parameters.
pub fn harmonic_scan(unit: &UnitModel, free: &[Param], data: &Dataset, sigma: (f64, f64)) -> Result<Vec<Harmonic>> {
    let (j, r) = weighted_jacobian(unit, free, data, sigma)?;
    let n = data.len();
    // Sensitivity of each sample's weighted residual to each link's angle (deg).
    let h = 1e-3;
    let r0 = residuals(unit, data)?;
    let mut g = vec![vec![[0.0; 6]; n]; 3];
    for (i, gi) in g.iter_mut().enumerate() {
        let mut shifted = data.clone();
        for s in &mut shifted.samples {
            s.theta_deg[i] += h;
        }
        let ri = residuals(unit, &shifted)?;
        for k in 0..n {
            for m in 0..6 {
                gi[k][m] = (ri[k][m] - r0[k][m]) / h / if m < 3 { sigma.0 } else { sigma.1 };
            }
        }
    }
    let jtj_inv = (j.transpose() * &j).pseudo_inverse(1e-12).map_err(|e| CalibError::Data(e.to_string()))?;
    let project = |c: &DVector<f64>| -> DVector<f64> {
        if j.ncols() == 0 {
            return c.clone();
        }
        c - &j * (&jtj_inv * (j.transpose() * c))
    };
    let rp = project(&r);
    let mut out = vec![];
    for i in 0..3 {
        for cycles in 2..=12 {
            let mut cs = DVector::zeros(6 * n);
            let mut cc = DVector::zeros(6 * n);
            for (k, smp) in data.samples.iter().enumerate() {
                let (si, co) = (cycles as f64 * smp.theta_deg[i].to_radians()).sin_cos();
                for m in 0..6 {
                    cs[6 * k + m] = g[i][k][m] * si;
                    cc[6 * k + m] = g[i][k][m] * co;
                }
            }
            let (ps, pc) = (project(&cs), project(&cc));
            let a = nalgebra::Matrix2::new(ps.dot(&ps), ps.dot(&pc), ps.dot(&pc), pc.dot(&pc));
            let b = nalgebra::Vector2::new(ps.dot(&rp), pc.dot(&rp));
            let Some(inv) = a.try_inverse() else { continue };
            // r = meas - pred, so the ripple that explains it enters with a minus sign.
            let coef = inv * b;
            out.push(Harmonic { link: i, cycles, drop: coef.dot(&b), amplitude_deg: coef.norm() });
        }
    }
    out.sort_by(|a, b| b.drop.total_cmp(&a.drop));
    Ok(out)
}

/// Names the strongest structure left in a residual no library effect explains: the best
/// link-angle ripple (fitted jointly with the model) or a drift over the session.
fn describe_structure(data: &Dataset, res: &[[f64; 6]], ripple: Option<Harmonic>, sigma: (f64, f64)) -> Unexplained {
    let (rr, _) = rms_norm(res);
    let t: Vec<f64> = data.samples.iter().map(|s| s.t_s).collect();
    let tm = t.iter().sum::<f64>() / t.len() as f64;
    let span = t.iter().cloned().fold(f64::MIN, f64::max) - t.iter().cloned().fold(f64::MAX, f64::min);
    let den: f64 = t.iter().map(|ti| (ti - tm).powi(2)).sum();
    let mut drift = 0.0;
    for ax in 0..3 {
        let num: f64 = t.iter().zip(res).map(|(ti, r)| (ti - tm) * r[ax]).sum();
        if den > 0.0 {
            drift += (num / den * span).powi(2);
        }
    }
    let drift = drift.sqrt();
    let description = match ripple {
        Some(h) if h.amplitude_deg > drift && h.amplitude_deg > 0.5 * sigma.0 => format!(
            "periodic in theta{}, {} cycles per revolution, {:.3} deg of link angle",
            h.link + 1,
            h.cycles,
            h.amplitude_deg
        ),
        _ if drift > 3.0 * sigma.0 => format!("drift over the session, {drift:.3} deg from start to end"),
        _ => "structured residual without a periodic or temporal pattern; see the residual heatmap".to_string(),
    };
    Unexplained { description, rms_rot_deg: rr }
}

/// summary.json in the layout.
pub fn summary_json(r: &ExplainResult) -> serde_json::Value {
    serde_json::json!({
        "noise_floor": {"rot_deg": r.noise_floor_rot_deg, "trans_mm": r.noise_floor_trans_mm, "method": r.noise_method},
        "initial": {"rms_rot_deg": r.initial_rms.0, "rms_trans_mm": r.initial_rms.1},
        "steps": r.steps.iter().map(|s| serde_json::json!({
            "effect": s.effect,
            "params": s.params,
            "std_errors": s.std_errors,
            "score": s.score,
            "rms_rot_deg_before": s.rms_rot_deg_before,
            "rms_rot_deg_after": s.rms_rot_deg_after,
            "rms_trans_mm_before": s.rms_trans_mm_before,
            "rms_trans_mm_after": s.rms_trans_mm_after,
            "evidence": s.evidence,
            "candidates": s.candidates,
        })).collect::<Vec<_>>(),
        "final_candidates": r.final_candidates,
        "unexplained": r.unexplained,
        "held_parameters": r.held,
    })
}

/// report.md: what was found, with the numbers and the plots' file names.
pub fn report_markdown(r: &ExplainResult, data_name: &str, plots: &[(String, String)]) -> String {
    let mut s = format!(
        "# Discrepancy report: {data_name}\n\n\
         Noise floor (per-sample RMS of the measurement noise): {:.4} deg, {:.4} mm ({}).\n\n\
         Starting model, held-out RMS after fitting its own effects: {:.4} deg, {:.4} mm.\n\n",
        r.noise_floor_rot_deg, r.noise_floor_trans_mm, r.noise_method, r.initial_rms.0, r.initial_rms.1
    );
    if r.steps.is_empty() {
        s += "No effect of the library explains a significant part of the held-out residual: nothing was added.\n\n";
    }
    let table = |cands: &[CandidateScore]| {
        let mut t = String::from(
            "| effect | params | score | share of structured misfit | significant | note |\n| --- | --- | --- | --- | --- | --- |\n",
        );
        for c in cands {
            t += &format!(
                "| {} | {} | {:.4} | {:.0}% | {} | {} |\n",
                c.effect,
                c.params_added,
                c.score,
                100.0 * c.excess_fraction,
                if c.significant { "yes" } else { "no" },
                c.note
            );
        }
        t
    };
    for (i, st) in r.steps.iter().enumerate() {
        s += &format!("## Step {}: {}\n\n", i + 1, st.effect);
        s += &format!(
            "Held-out RMS {:.4} -> {:.4} deg, {:.4} -> {:.4} mm (score {:.3}).\n\nEvidence: {}\n\n",
            st.rms_rot_deg_before,
            st.rms_rot_deg_after,
            st.rms_trans_mm_before,
            st.rms_trans_mm_after,
            st.score,
            st.evidence
        );
        s += "| parameter | value | std. error |\n| --- | --- | --- |\n";
        for (k, v) in &st.params {
            s += &format!("| {k} | {v:.5} | {:.5} |\n", st.std_errors.get(k).copied().unwrap_or(f64::NAN));
        }
        s += "\nCandidates (held-out cross-validation):\n\n";
        s += &table(&st.candidates);
        for (title, file) in plots.iter().filter(|p| p.0.starts_with(&format!("step {}:", i + 1))) {
            s += &format!("\n![{title}]({file})\n");
        }
        s += "\n";
    }
    if !r.final_candidates.is_empty() {
        s += "## Last round: no candidate significant\n\n";
        s += &table(&r.final_candidates);
        s += "\n";
    }
    if !r.unexplained.is_empty() {
        s += "## Unexplained structure\n\n";
        for u in &r.unexplained {
            s += &format!("- {} (held-out rotation RMS {:.4} deg)\n", u.description, u.rms_rot_deg);
        }
        s += "\nNo effect of the library fits this pattern; it is reported, not forced onto a name.\n\n";
    }
    if !r.held.is_empty() {
        s +=
            &format!("Parameters the data cannot separate (held at their starting values): {}.\n\n", r.held.join(", "));
    }
    for (title, file) in plots.iter().filter(|p| !p.0.starts_with("step ")) {
        s += &format!("![{title}]({file})\n\n");
    }
    s += "The final unit model is `unit.toml` (loadable by `abvs kin fk --unit`, `abvs sim dataset --unit`).\n";
    s
}
