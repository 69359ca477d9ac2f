//! Which effects to name, decided jointly on held-out evidence: every set of up to
//! `max_joint` candidate effects is scored by its cross-validated chi-square (linearised around
//! the current model, see [`Design`]) plus `ln(rows)` per parameter. The best set whose every
//! member is necessary (removes more than its penalty and a real share of what the others
//! leave) and physically plausible wins. Structure outside the library (a ripple of any link and
//! cycle count, with its second harmonic, a drift over the session) competes under the same
//! penalty: an outside description with the best library set beside it displaces the best
//! library set where it scores better, and members that explain nothing beyond the outside
//! structure are dropped. Effects with several forms (one wheel, a common scale, the readings of
//! hinge_backlash) compete in each, a set carrying one. A named effect that another candidate
//! replaces almost as well is reported as ambiguous, not named.
use super::design::{BlockKind, Design};
use super::structure::{Harmonic, Outside};
use super::CandidateScore;
use crate::identify::{Param, HEAD_LAYOUTS};
use abvs_eye::unit::{BacklashForm, Effect};
use std::collections::HashMap;

pub struct SelectOptions {
    /// Held-out chi-square a parameter must remove to count (`ln` of the rows).
    pub penalty: f64,
    /// Expected held-out chi-square of a model that leaves only noise (the rows).
    pub floor: f64,
    /// Share of the structured misfit the others leave that a member must remove.
    pub min_share: f64,
    pub max_joint: usize,
    /// A candidate parameter is identifiable if its standard error is below this share of its
    /// typical size (as in `identify`).
    pub ident_ratio: f64,
    /// A substitute whose penalised held-out chi-square is within `2 penalty` plus this share
    /// of a member's marginal evidence makes it ambiguous (the data do not decide).
    pub ambiguity_margin: f64,
}

/// A candidate reduced to its identifiable parameters.
#[derive(Clone)]
pub struct Cand {
    pub effect: Effect,
    pub cols: Vec<usize>,
    pub params: Vec<Param>,
    /// A tied form ([`BlockKind::Wheel`], [`BlockKind::CommonScale`]): fewer columns stand
    /// for the effect's parameters (the params are the tie's scalars).
    pub tied: Option<BlockKind>,
    /// Which form of the effect, where it has several (for the report).
    pub form: Option<String>,
}

impl Cand {
    /// The parameters' values for this candidate's fitted column coefficients `x`.
    pub fn values(&self, x: &[f64]) -> Vec<f64> {
        x.to_vec()
    }
    /// Largest fitted size relative to the plausible maximum, for coefficients `x`.
    fn size_ratio(&self, x: &[f64]) -> f64 {
        match self.tied {
            Some(BlockKind::Wheel { .. }) => x[0].hypot(x[1]) / self.params[0].plausible_max(),
            _ => x.iter().zip(&self.params).map(|(v, p)| v.abs() / p.plausible_max()).fold(0.0, f64::max),
        }
    }
}

pub struct Named {
    pub effect: Effect,
    /// The form fitted, where the effect has several.
    pub form: Option<String>,
    /// Held-out chi-square it removes given the others.
    pub marginal: f64,
    /// Candidates that replace it almost as well (empty: named without doubt).
    pub alternatives: Vec<(Effect, f64)>,
    /// Identifiable parameters to fit.
    pub params: Vec<Param>,
}

pub struct Choice {
    pub named: Vec<Named>,
    pub table: Vec<CandidateScore>,
    /// The best outside structure given the chosen set, when it is significant there.
    pub outside: Option<Outside>,
    /// Held-out chi-square of the base.
    pub chi_base: f64,
    pub candidates: Vec<Cand>,
}

struct Scorer<'a> {
    d: &'a Design,
    base: Vec<usize>,
    cands: &'a [Cand],
    outs: Vec<OutsideCand>,
    memo: HashMap<(Vec<usize>, Option<usize>), f64>,
}

impl Scorer<'_> {
    fn cols(&self, set: &[usize], out: Option<usize>) -> Vec<usize> {
        let mut c = self.base.clone();
        for &i in set {
            c.extend(&self.cands[i].cols);
        }
        if let Some(r) = out {
            c.extend(&self.outs[r].cols);
        }
        c
    }
    fn chi(&mut self, set: &[usize], out: Option<usize>) -> f64 {
        let mut key = set.to_vec();
        key.sort();
        if let Some(v) = self.memo.get(&(key.clone(), out)) {
            return *v;
        }
        let v = self.d.cv_chi2(&self.cols(&key, out));
        self.memo.insert((key, out), v);
        v
    }
    fn k(&self, set: &[usize], out: Option<usize>) -> f64 {
        (set.iter().map(|&i| self.cands[i].cols.len()).sum::<usize>() + out.map_or(0, |r| self.outs[r].cols.len()))
            as f64
    }
    fn pchi(&mut self, set: &[usize], out: Option<usize>, pen: f64) -> f64 {
        self.chi(set, out) + pen * self.k(set, out)
    }
    /// Largest fitted size relative to its plausible maximum, per member of the set.
    fn size_ratio(&self, set: &[usize], out: Option<usize>, member: usize) -> f64 {
        let cols = self.cols(set, out);
        let (x, _) = self.d.fit(&cols);
        let c = &self.cands[member];
        let xs: Vec<f64> =
            c.cols.iter().map(|col| x[cols.iter().position(|k| k == col).expect("member column in set")]).collect();
        c.size_ratio(&xs)
    }
    /// code_wheel_eccentricity is fitted per head with free phases (head placement is a design
    /// fact); one eccentric wheel shows every head the same amplitude. Per-head amplitudes that
    /// differ beyond their uncertainty (chi-square, 2 dof, 99.9%) describe something else (a
    /// ripple of one link, a scale error), not the wheel.
    fn not_one_wheel(&self, set: &[usize], out: Option<usize>, member: usize) -> Option<String> {
        let cols = self.cols(set, out);
        let (x, _) = self.d.fit(&cols);
        let se = self.d.std_errors(&cols);
        let c = &self.cands[member];
        let mut xy = [[0.0f64; 2]; 3];
        let mut se_max: f64 = 0.0;
        for (col, p) in c.cols.iter().zip(&c.params) {
            let at = cols.iter().position(|k| k == col).expect("member column in set");
            xy[p.index % 3][p.index / 3] = x[at];
            se_max = se_max.max(se[at]);
        }
        let amp = xy.map(|v| v[0].hypot(v[1]));
        let mean = amp.iter().sum::<f64>() / 3.0;
        let chi: f64 = amp.iter().map(|a| ((a - mean) / se_max.max(1e-9)).powi(2)).sum();
        (chi > 13.8).then(|| {
            format!(
                "per-head amplitudes {:.1}, {:.1}, {:.1} um differ beyond their uncertainty ({se_max:.1} um): not one eccentric wheel",
                amp[0], amp[1], amp[2]
            )
        })
    }

    /// Why a member of `set` does not hold (None: it holds).
    fn member_fails(&mut self, set: &[usize], out: Option<usize>, i: usize, o: &SelectOptions) -> Option<String> {
        let rest: Vec<usize> = set.iter().copied().filter(|&j| j != i).collect();
        let (with, without) = (self.chi(set, out), self.chi(&rest, out));
        let m = without - with;
        let k = self.cands[i].cols.len() as f64;
        if m <= o.penalty * k {
            return Some("explains less than its parameters' penalty".into());
        }
        let structured = (without - o.floor).max(1e-9);
        if m < o.min_share * structured {
            return Some(format!("explains only {:.0}% of the structured misfit", 100.0 * m / structured));
        }
        if self.cands[i].effect == Effect::CodeWheelEccentricity && self.cands[i].tied.is_none() {
            if let Some(why) = self.not_one_wheel(set, out, i) {
                return Some(why);
            }
        }
        let ratio = self.size_ratio(set, out, i);
        if ratio > 1.0 {
            return Some(format!(
                "fitted size {ratio:.1}x the plausible maximum: it would be absorbing something else"
            ));
        }
        None
    }
    fn valid(&mut self, set: &[usize], out: Option<usize>, o: &SelectOptions) -> bool {
        set.iter().all(|&i| self.member_fails(set, out, i, o).is_none())
    }
}

fn subsets(n: usize, max: usize) -> Vec<Vec<usize>> {
    let mut out = vec![vec![]];
    for i in 0..n {
        let grown: Vec<Vec<usize>> =
            out.iter().filter(|s| s.len() < max).map(|s| [s.clone(), vec![i]].concat()).collect();
        out.extend(grown);
    }
    out
}

/// Drops the columns whose parameters the data do not determine given the base, worst first.
fn reduce_identifiable(d: &Design, base: &[usize], cols: &mut Vec<usize>, params: &mut Vec<Param>, o: &SelectOptions) {
    while !cols.is_empty() {
        let all: Vec<usize> = base.iter().chain(cols.iter()).copied().collect();
        let se = d.std_errors(&all);
        let (worst, ratio) = cols
            .iter()
            .enumerate()
            .map(|(k, _)| (k, se[base.len() + k] / params[k].scale()))
            .fold((0, 0.0), |a, b| if b.1 > a.1 || !b.1.is_finite() { b } else { a });
        if ratio.is_finite() && ratio <= o.ident_ratio {
            break;
        }
        cols.remove(worst);
        params.remove(worst);
    }
}

/// Reduces each candidate block to its identifiable parameters (worst standard error out
/// first, given the base).
pub fn candidates(d: &Design, o: &SelectOptions) -> Vec<(Effect, Option<Cand>)> {
    let base = d.base();
    let mut out = vec![];
    for blk in &d.blocks {
        let BlockKind::Effect(e) = blk.kind else { continue };
        let mut cols: Vec<usize> = blk.cols.clone().collect();
        let mut params = blk.params.clone();
        reduce_identifiable(d, &base, &mut cols, &mut params, o);
        let form =
            (e == Effect::HingeBacklash).then(|| "any mix of its readings (the parameters the data determine)".into());
        let cand = (!cols.is_empty()).then_some(Cand { effect: e, cols, params, tied: None, form });
        out.push((e, cand));
    }
    out
}

/// The one-wheel form of `e`, a candidate beside the free one: the eccentricity of one wheel
/// (two parameters, the heads at the best-fitting layout of [`HEAD_LAYOUTS`]), one scale common
/// to the links (one pitch). Tied, the two separate: one wheel shows its heads a scale-like
/// term at different phases, never the same one, where free per-head terms can mimic a common
/// scale. Which form a set carries is decided by the sets' penalised held-out chi-square.
fn one_wheel(d: &Design, e: Effect) -> Option<Cand> {
    let base = d.base();
    let chi = |c: &[usize]| d.cv_chi2(&base.iter().chain(c).copied().collect::<Vec<_>>());
    d.blocks
        .iter()
        .filter(|b| {
            matches!(b.kind, BlockKind::Wheel { .. } | BlockKind::CommonScale)
                && b.params.first().map(|p| p.effect) == Some(e)
        })
        .map(|b| {
            let cols: Vec<usize> = b.cols.clone().collect();
            let form = match b.kind {
                BlockKind::Wheel { layout } => format!("one wheel, {}", HEAD_LAYOUTS[layout].0),
                _ => "one scale common to the three links".into(),
            };
            (chi(&cols), Cand { effect: e, cols, params: b.params.clone(), tied: Some(b.kind), form: Some(form) })
        })
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map(|c| c.1)
}

/// The readings of hinge_backlash ([`BacklashForm`]), each a candidate beside the free mix:
/// a lag of each link, of the platform about each hinge axis, of the platform along its own last
/// motion. Their signatures differ in where and how the direction of approach shows, so the
/// held-out comparison (same penalty as every candidate) picks the one the data support; a
/// reading with fewer parameters wins where it fits as well.
fn backlash_forms(d: &Design, o: &SelectOptions) -> Vec<Cand> {
    let Some(blk) = d.blocks.iter().find(|b| b.kind == BlockKind::Effect(Effect::HingeBacklash)) else { return vec![] };
    if blk.cols.len() != Effect::HingeBacklash.param_names().len() {
        return vec![];
    }
    let base = d.base();
    BacklashForm::ALL
        .into_iter()
        .filter_map(|f| {
            let mut cols: Vec<usize> = f.indices().map(|k| blk.cols.start + k).collect();
            let mut params: Vec<Param> = f.indices().map(|k| blk.params[k]).collect();
            reduce_identifiable(d, &base, &mut cols, &mut params, o);
            (!cols.is_empty()).then(|| Cand {
                effect: Effect::HingeBacklash,
                cols,
                params,
                tied: None,
                form: Some(f.describe().into()),
            })
        })
        .collect()
}

/// A description outside the library, competing with library sets under the same penalty: a
/// ripple of one link's angle, that ripple with its second harmonic, a drift over the session.
#[derive(Clone)]
struct OutsideCand {
    kind: OutsideKind,
    cols: Vec<usize>,
}

#[derive(Clone, Copy)]
enum OutsideKind {
    Ripple { link: usize, cycles: usize },
    WithHarmonic { link: usize, cycles: usize },
    Drift,
}

fn outside_cands(d: &Design) -> Vec<OutsideCand> {
    let mut out = vec![];
    for blk in &d.blocks {
        match blk.kind {
            BlockKind::Ripple { link, cycles } => {
                out.push(OutsideCand { kind: OutsideKind::Ripple { link, cycles }, cols: blk.cols.clone().collect() });
                let second = d.blocks.iter().find(|b| b.kind == BlockKind::Ripple { link, cycles: 2 * cycles });
                if let Some(h) = second {
                    out.push(OutsideCand {
                        kind: OutsideKind::WithHarmonic { link, cycles },
                        cols: blk.cols.clone().chain(h.cols.clone()).collect(),
                    });
                }
            }
            BlockKind::Drift => out.push(OutsideCand { kind: OutsideKind::Drift, cols: blk.cols.clone().collect() }),
            _ => {}
        }
    }
    out
}

/// The outside descriptions that explain most on top of `set`, best first (index, penalised
/// chi-square).
fn best_outside(s: &mut Scorer, set: &[usize], pen: f64, n: usize) -> Vec<(usize, f64)> {
    let mut v: Vec<(usize, f64)> = (0..s.outs.len()).map(|r| (r, s.pchi(set, Some(r), pen))).collect();
    v.sort_by(|a, b| a.1.total_cmp(&b.1));
    v.truncate(n);
    v
}

fn best_valid(s: &mut Scorer, all: &[Vec<usize>], out: Option<usize>, o: &SelectOptions) -> Vec<usize> {
    let mut scored: Vec<(f64, &Vec<usize>)> = all.iter().map(|set| (s.pchi(set, out, o.penalty), set)).collect();
    scored.sort_by(|a, b| a.0.total_cmp(&b.0));
    for (_, set) in scored {
        if s.valid(set, out, o) {
            return set.clone();
        }
    }
    vec![]
}

pub fn choose(d: &Design, o: &SelectOptions) -> Choice {
    let listed = candidates(d, o);
    let mut cands: Vec<Cand> = listed.iter().filter_map(|c| c.1.clone()).collect();
    for e in [Effect::CodeWheelEccentricity, Effect::EncoderScale] {
        cands.extend(one_wheel(d, e));
    }
    cands.extend(backlash_forms(d, o));
    let mut s = Scorer { d, base: d.base(), cands: &cands, outs: outside_cands(d), memo: HashMap::new() };
    let chi_base = s.chi(&[], None);
    // A set carries each effect in one form.
    let all: Vec<Vec<usize>> = subsets(cands.len(), o.max_joint)
        .into_iter()
        .filter(|set| {
            set.iter().enumerate().all(|(k, &i)| set[..k].iter().all(|&j| cands[j].effect != cands[i].effect))
        })
        .collect();
    let lib = best_valid(&mut s, &all, None, o);
    let mut chosen = lib.clone();
    let mut out_note: Option<(usize, String)> = None;
    // Outside structure competes with the best library set on the same footing: each of the
    // outside descriptions that explain most (alone, or on top of that set), with the best valid
    // library set beside it. A library set is named only where it scores better.
    let mut best = s.pchi(&lib, None, o.penalty);
    let mut tops = best_outside(&mut s, &[], o.penalty, 3);
    tops.extend(best_outside(&mut s, &lib, o.penalty, 3));
    for (r, _) in tops {
        let set = best_valid(&mut s, &all, Some(r), o);
        let score = s.pchi(&set, Some(r), o.penalty);
        if score < best {
            best = score;
            chosen = set;
            out_note = Some((r, outside_name(&s.outs[r])));
        }
    }
    // Every member must also explain something beyond the best outside structure on top of it.
    if let Some(&(r, p_r)) = best_outside(&mut s, &chosen, o.penalty, 1).first() {
        if p_r < s.pchi(&chosen, None, o.penalty) {
            let keep: Vec<usize> =
                chosen.iter().copied().filter(|&i| s.member_fails(&chosen, Some(r), i, o).is_none()).collect();
            if keep.len() < chosen.len() {
                out_note = Some((r, outside_name(&s.outs[r])));
            }
            chosen = keep;
        }
    }
    let chi_chosen = s.chi(&chosen, None);
    // Outside structure significant on top of the set: members are weighed beside it.
    let sig_out = best_outside(&mut s, &chosen, o.penalty, 1)
        .first()
        .filter(|(_, p_r)| *p_r < s.pchi(&chosen, None, o.penalty))
        .map(|(r, _)| *r);

    // Marginal evidence and substitutes of each member.
    let mut named = vec![];
    for &i in &chosen {
        let rest: Vec<usize> = chosen.iter().copied().filter(|&j| j != i).collect();
        let m = s.chi(&rest, sig_out) - s.chi(&chosen, sig_out);
        let here = s.pchi(&chosen, sig_out, o.penalty);
        let mut alternatives: Vec<(Effect, f64)> = vec![];
        for j in 0..cands.len() {
            // Another form of a member is not a substitute for it; an effect is listed once.
            if chosen.iter().any(|&c| cands[c].effect == cands[j].effect)
                || alternatives.iter().any(|a| a.0 == cands[j].effect)
            {
                continue;
            }
            let swapped: Vec<usize> = rest.iter().copied().chain([j]).collect();
            let there = s.pchi(&swapped, sig_out, o.penalty);
            if there - here < 2.0 * o.penalty + o.ambiguity_margin * m && s.size_ratio(&swapped, sig_out, j) <= 1.0 {
                alternatives.push((cands[j].effect, s.chi(&rest, sig_out) - s.chi(&swapped, sig_out)));
            }
        }
        named.push(Named {
            effect: cands[i].effect,
            form: cands[i].form.clone(),
            marginal: m,
            alternatives,
            params: cands[i].params.clone(),
        });
    }
    named.sort_by(|a, b| b.marginal.total_cmp(&a.marginal));

    // The table: every candidate alone against the base, and why it was or was not named.
    let structured = (chi_base - o.floor).max(0.0);
    let mut table = vec![];
    for (e, cand) in &listed {
        let Some(c) = cand else {
            table.push(CandidateScore {
                effect: e.name().into(),
                params_added: 0,
                score: 0.0,
                excess_fraction: 0.0,
                significant: false,
                note: "not identifiable from these data".into(),
            });
            continue;
        };
        // The form named, else the free one.
        let i = chosen
            .iter()
            .copied()
            .find(|&j| cands[j].effect == c.effect)
            .or_else(|| cands.iter().position(|x| x.effect == c.effect))
            .expect("listed");
        let drop = chi_base - s.chi(&[i], None);
        let k = cands[i].cols.len();
        let n = named.iter().find(|n| n.effect == c.effect);
        let note = match n {
            Some(n) if !n.alternatives.is_empty() => {
                format!("ambiguous with {}", n.alternatives.iter().map(|a| a.0.name()).collect::<Vec<_>>().join(", "))
            }
            Some(_) if chosen.len() > 1 => format!(
                "named, jointly with {}",
                chosen.iter().filter(|&&j| j != i).map(|&j| cands[j].effect.name()).collect::<Vec<_>>().join(", ")
            ),
            Some(_) => "named".into(),
            None => {
                // Why not: judged as an addition to the chosen set.
                let mut with: Vec<usize> = chosen.clone();
                with.push(i);
                let rip = out_note.as_ref().map(|r| r.0);
                let why: String = match s.member_fails(&with, rip, i, o) {
                    Some(why) => match &out_note {
                        Some((_, rn)) if s.member_fails(&with, None, i, o).is_none() => {
                            format!("explains nothing beyond {rn}")
                        }
                        _ => why,
                    },
                    None => "redundant with the named set".into(),
                };
                if chosen.is_empty() {
                    why
                } else {
                    format!("{why} (beyond the named set)")
                }
            }
        };
        table.push(CandidateScore {
            effect: e.name().into(),
            params_added: k,
            score: (drop - o.penalty * k as f64) / chi_base.max(1e-300),
            excess_fraction: if structured > 0.0 { drop / structured } else { 0.0 },
            significant: n.is_some(),
            note,
        });
    }
    table.sort_by(|a, b| b.score.total_cmp(&a.score));

    // The outside structure left on top of the chosen set, if significant.
    let outside = best_outside(&mut s, &chosen, o.penalty, 1).first().and_then(|&(r, p_r)| {
        let drop = chi_chosen - s.chi(&chosen, Some(r));
        (p_r < s.pchi(&chosen, None, o.penalty)).then(|| {
            let cols = s.cols(&chosen, Some(r));
            let (x, _) = d.fit(&cols);
            let k = s.outs[r].cols.len();
            let c = &x[x.len() - k..];
            match s.outs[r].kind {
                OutsideKind::Ripple { link, cycles } => Outside::Ripple(Harmonic {
                    link,
                    cycles,
                    drop,
                    amplitude_deg: c[0].hypot(c[1]),
                    second_harmonic_deg: None,
                }),
                OutsideKind::WithHarmonic { link, cycles } => Outside::Ripple(Harmonic {
                    link,
                    cycles,
                    drop,
                    amplitude_deg: c[0].hypot(c[1]),
                    second_harmonic_deg: Some(c[2].hypot(c[3])),
                }),
                OutsideKind::Drift => Outside::Drift { end_deg: c.iter().map(|v| v * v).sum::<f64>().sqrt(), drop },
            }
        })
    });
    Choice { named, table, outside, chi_base, candidates: cands }
}

fn outside_name(c: &OutsideCand) -> String {
    match c.kind {
        OutsideKind::Ripple { link, cycles } => format!("a {cycles}-cycle ripple of theta{}", link + 1),
        OutsideKind::WithHarmonic { link, cycles } => {
            format!("a {cycles}-cycle ripple of theta{} with its second harmonic", link + 1)
        }
        OutsideKind::Drift => "a drift over the session".into(),
    }
}

fn ripple_name(d: &Design, r: usize) -> String {
    match d.blocks[r].kind {
        BlockKind::Ripple { link, cycles } => format!("a {cycles}-cycle ripple of theta{}", link + 1),
        _ => "a ripple".into(),
    }
}

/// What a parameter stuck at a bound is probably absorbing: the candidate effect or ripple
/// whose signature reproduces most of its column.
pub fn absorbing(d: &Design, col: usize, cands: &[Cand]) -> String {
    let mut best = (String::from("nothing in the library"), 0.0);
    for c in cands {
        let share = d.explained_share(col, &c.cols);
        if share > best.1 {
            best = (c.effect.name().to_string(), share);
        }
    }
    for (b, blk) in d.blocks.iter().enumerate() {
        if let BlockKind::Ripple { .. } = blk.kind {
            let share = d.explained_share(col, &blk.cols.clone().collect::<Vec<_>>());
            if share > best.1 {
                best = (ripple_name(d, b), share);
            }
        }
    }
    if best.1 < 0.3 {
        return "no missing effect mimics it: a unit far from nominal, or a wrong starting model".into();
    }
    format!("{} (its signature reproduces {:.0}% of this parameter's)", best.0, 100.0 * best.1)
}
