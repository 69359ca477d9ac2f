//! Which effects to name, decided jointly on held-out evidence: every set of up to
//! `max_joint` candidate effects is scored by its cross-validated chi-square (linearised around
//! the current model, see [`Design`]) plus `ln(rows)` per parameter. The best set whose every
//! member is necessary (removes more than its penalty and a real share of what the others
//! leave) and physically plausible wins. The generic link-angle ripple competes only for what
//! no library set explains: it displaces library effects only where it explains more than the
//! best set, and then only members that explain nothing beyond it are dropped. A named effect
//! that another candidate replaces almost as well is reported as ambiguous, not named.
use super::design::{wheel_heads, BlockKind, Design, HEAD_LAYOUTS};
use super::structure::Harmonic;
use super::CandidateScore;
use crate::identify::Param;
use abvs_eye::unit::Effect;
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
    /// for the effect's parameters.
    pub tied: Option<BlockKind>,
}

impl Cand {
    /// The parameters' values for this candidate's fitted column coefficients `x`.
    pub fn values(&self, x: &[f64]) -> Vec<f64> {
        match self.tied {
            Some(BlockKind::Wheel { layout }) => {
                let h = wheel_heads(&HEAD_LAYOUTS[layout].1, x[0], x[1]);
                [h[0][0], h[1][0], h[2][0], h[0][1], h[1][1], h[2][1]].to_vec()
            }
            Some(BlockKind::CommonScale) => vec![x[0]; 3],
            _ => x.to_vec(),
        }
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
    /// The best ripple given the chosen set, when it is significant there.
    pub ripple: Option<Harmonic>,
    /// Held-out chi-square of the base.
    pub chi_base: f64,
    pub candidates: Vec<Cand>,
}

struct Scorer<'a> {
    d: &'a Design,
    base: Vec<usize>,
    cands: &'a [Cand],
    memo: HashMap<(Vec<usize>, Option<usize>), f64>,
}

impl Scorer<'_> {
    fn cols(&self, set: &[usize], ripple: Option<usize>) -> Vec<usize> {
        let mut c = self.base.clone();
        for &i in set {
            c.extend(&self.cands[i].cols);
        }
        if let Some(r) = ripple {
            c.extend(self.d.blocks[r].cols.clone());
        }
        c
    }
    fn chi(&mut self, set: &[usize], ripple: Option<usize>) -> f64 {
        let mut key = set.to_vec();
        key.sort();
        if let Some(v) = self.memo.get(&(key.clone(), ripple)) {
            return *v;
        }
        let v = self.d.cv_chi2(&self.cols(&key, ripple));
        self.memo.insert((key, ripple), v);
        v
    }
    fn k(&self, set: &[usize], ripple: Option<usize>) -> f64 {
        (set.iter().map(|&i| self.cands[i].cols.len()).sum::<usize>() + ripple.map_or(0, |_| 2)) as f64
    }
    fn pchi(&mut self, set: &[usize], ripple: Option<usize>, pen: f64) -> f64 {
        self.chi(set, ripple) + pen * self.k(set, ripple)
    }
    /// Largest fitted size relative to its plausible maximum, per member of the set.
    fn size_ratio(&self, set: &[usize], ripple: Option<usize>, member: usize) -> f64 {
        let cols = self.cols(set, ripple);
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
    fn not_one_wheel(&self, set: &[usize], ripple: Option<usize>, member: usize) -> Option<String> {
        let cols = self.cols(set, ripple);
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
    fn member_fails(&mut self, set: &[usize], ripple: Option<usize>, i: usize, o: &SelectOptions) -> Option<String> {
        let rest: Vec<usize> = set.iter().copied().filter(|&j| j != i).collect();
        let (with, without) = (self.chi(set, ripple), self.chi(&rest, ripple));
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
            if let Some(why) = self.not_one_wheel(set, ripple, i) {
                return Some(why);
            }
        }
        let ratio = self.size_ratio(set, ripple, i);
        if ratio > 1.0 {
            return Some(format!(
                "fitted size {ratio:.1}x the plausible maximum: it would be absorbing something else"
            ));
        }
        None
    }
    fn valid(&mut self, set: &[usize], ripple: Option<usize>, o: &SelectOptions) -> bool {
        set.iter().all(|&i| self.member_fails(set, ripple, i, o).is_none())
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

/// Reduces each candidate block to its identifiable parameters (worst standard error out
/// first, given the base).
pub fn candidates(d: &Design, o: &SelectOptions) -> Vec<(Effect, Option<Cand>)> {
    let base = d.base();
    let mut out = vec![];
    for blk in &d.blocks {
        let BlockKind::Effect(e) = blk.kind else { continue };
        let mut cols: Vec<usize> = blk.cols.clone().collect();
        let mut params = blk.params.clone();
        while !cols.is_empty() {
            let all: Vec<usize> = base.iter().chain(&cols).copied().collect();
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
        let cand = (!cols.is_empty()).then_some(Cand { effect: e, cols, params, tied: None });
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
            (chi(&cols), Cand { effect: e, cols, params: b.params.clone(), tied: Some(b.kind) })
        })
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map(|c| c.1)
}

/// The best ripple added to `set` (block index, chi-square with it).
fn best_ripple(s: &mut Scorer, set: &[usize]) -> Option<(usize, f64)> {
    let ripples: Vec<usize> =
        (0..s.d.blocks.len()).filter(|&b| matches!(s.d.blocks[b].kind, BlockKind::Ripple { .. })).collect();
    ripples.into_iter().map(|r| (r, s.chi(set, Some(r)))).min_by(|a, b| a.1.total_cmp(&b.1))
}

fn best_valid(s: &mut Scorer, all: &[Vec<usize>], ripple: Option<usize>, o: &SelectOptions) -> Vec<usize> {
    let mut scored: Vec<(f64, &Vec<usize>)> = all.iter().map(|set| (s.pchi(set, ripple, o.penalty), set)).collect();
    scored.sort_by(|a, b| a.0.total_cmp(&b.0));
    for (_, set) in scored {
        if s.valid(set, ripple, o) {
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
    let mut s = Scorer { d, base: d.base(), cands: &cands, memo: HashMap::new() };
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
    let mut ripple_note: Option<(usize, String)> = None;
    // The ripple competes for what the best library set leaves or explains no better.
    if let Some((r, chi_r)) = best_ripple(&mut s, &[]) {
        if chi_r + 2.0 * o.penalty < s.pchi(&lib, None, o.penalty) {
            chosen = best_valid(&mut s, &all, Some(r), o);
            ripple_note = Some((r, ripple_name(d, r)));
        }
    }
    // Every member must also explain something beyond the best ripple on top of the set.
    if let Some((r, chi_r)) = best_ripple(&mut s, &chosen) {
        if chi_r + 2.0 * o.penalty < s.chi(&chosen, None) {
            let keep: Vec<usize> =
                chosen.iter().copied().filter(|&i| s.member_fails(&chosen, Some(r), i, o).is_none()).collect();
            if keep.len() < chosen.len() {
                ripple_note = Some((r, ripple_name(d, r)));
            }
            chosen = keep;
        }
    }
    let chi_chosen = s.chi(&chosen, None);

    // Marginal evidence and substitutes of each member.
    let mut named = vec![];
    for &i in &chosen {
        let rest: Vec<usize> = chosen.iter().copied().filter(|&j| j != i).collect();
        let m = s.chi(&rest, None) - chi_chosen;
        let here = s.pchi(&chosen, None, o.penalty);
        let mut alternatives = vec![];
        for j in 0..cands.len() {
            // Another form of a member is not a substitute for it.
            if chosen.iter().any(|&c| cands[c].effect == cands[j].effect) {
                continue;
            }
            let swapped: Vec<usize> = rest.iter().copied().chain([j]).collect();
            let there = s.pchi(&swapped, None, o.penalty);
            if there - here < 2.0 * o.penalty + o.ambiguity_margin * m && s.size_ratio(&swapped, None, j) <= 1.0 {
                alternatives.push((cands[j].effect, s.chi(&rest, None) - s.chi(&swapped, None)));
            }
        }
        named.push(Named { effect: cands[i].effect, marginal: m, alternatives, params: cands[i].params.clone() });
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
                let rip = ripple_note.as_ref().map(|r| r.0);
                let why: String = match s.member_fails(&with, rip, i, o) {
                    Some(why) => match &ripple_note {
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

    // The ripple left on top of the chosen set, if significant.
    let ripple = best_ripple(&mut s, &chosen).and_then(|(r, chi_r)| {
        let drop = chi_chosen - chi_r;
        (drop > 2.0 * o.penalty).then(|| {
            let BlockKind::Ripple { link, cycles } = d.blocks[r].kind else { unreachable!("ripple block") };
            let cols = s.cols(&chosen, Some(r));
            let (x, _) = d.fit(&cols);
            let n = x.len();
            Harmonic { link, cycles, drop, amplitude_deg: x[n - 2].hypot(x[n - 1]) }
        })
    });
    Choice { named, table, ripple, chi_base, candidates: cands }
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
