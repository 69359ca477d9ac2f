//! Identification of a unit's physical parameters from a dataset: weighted Levenberg-Marquardt
//! on the unit model of abvs-eye (the same model the simulator runs), with an identifiability
//! check. Used by `mh` (camera_mount only), `hybrid` (all static effects) and the discrepancy
//! workflow.
//!
//! Residual of a sample: the rotation vector of `R_pred^T R_meas` (deg) and `t_meas - t_pred`
//! (mm), weighted by `1 / sigma_rot` and `1 / sigma_trans` so both count in units of noise.
//!
//! Identifiability: a parameter is fitted only if the data determine it: its standard error
//! (from the Gauss-Newton covariance at the noise level) must be below `ident_ratio` times its
//! typical size (effects.md). Parameters failing that are held at their starting values and
//! reported with the parameters they are confounded with, worst first, one at a time.
use crate::error::{CalibError, Result};
use abvs_eye::dataset::Dataset;
use abvs_eye::lm::{levenberg_marquardt, Damping, LmProblem};
use abvs_eye::pose::rotation_vector;
use abvs_eye::unit::{Effect, UnitModel};
use abvs_eye::Pose;
use nalgebra::{DMatrix, DVector};

/// One free scalar: an effect and the index into its parameter vector, or, for a tied form,
/// the index into the tie's own scalars (which set all of the effect's parameters).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Param {
    pub effect: Effect,
    pub index: usize,
    pub tie: Option<Tie>,
}

/// A physical tie among one effect's parameters, fitted through fewer scalars. One shared code
/// wheel makes them: its eccentricity shows every head the same amplitude at a phase set by the
/// head's place on the wheel, and its pitch is one scale for all links. Free, the per-head and
/// per-link parameters can trade sizes between scale and eccentricity (a common scale looks like
/// a slow part of three free sinusoids); tied, they cannot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Tie {
    /// code_wheel_eccentricity of one wheel read by heads at [`HEAD_LAYOUTS`]`[layout]`: the
    /// offset's components `(e cos phi, e sin phi)` (um).
    WheelAt { layout: usize },
    /// encoder_scale common to the three links: one relative error.
    CommonScale,
}

/// Where the three read heads may sit on the shared wheel (deg, at readings 0), as the design
/// documents allow: on the spec's zero markers (conventions.md: 0, 9.944, 180 deg), or 120 deg
/// apart under the legs (psi = 90, 210, 330 deg).
pub const HEAD_LAYOUTS: [(&str, [f64; 3]); 2] = [
    ("heads on the zero markers (0, 9.944, 180 deg)", [0.0, 9.944, 180.0]),
    ("heads under the legs (90, 210, 330 deg)", [90.0, 210.0, 330.0]),
];

/// Per-head eccentricity `[x_i, y_i]` (um, the unit model's per-head form) of one wheel
/// offset `(a, b) = (e cos phi, e sin phi)` read by heads at `layout` (deg):
/// `x_i = e cos(s_i - phi)`, `y_i = e sin(s_i - phi)`.
pub fn wheel_heads(layout: &[f64; 3], a: f64, b: f64) -> [[f64; 2]; 3] {
    std::array::from_fn(|i| {
        let (si, co) = layout[i].to_radians().sin_cos();
        [a * co + b * si, a * si - b * co]
    })
}

impl Tie {
    /// The effect whose parameters it ties.
    pub fn effect(self) -> Effect {
        match self {
            Tie::WheelAt { .. } => Effect::CodeWheelEccentricity,
            Tie::CommonScale => Effect::EncoderScale,
        }
    }
    pub fn names(self) -> Vec<String> {
        match self {
            Tie::WheelAt { .. } => vec!["one_wheel.e_cos_phi_um".into(), "one_wheel.e_sin_phi_um".into()],
            Tie::CommonScale => vec!["common.relative_error".into()],
        }
    }
    /// The effect's parameters for the tie's scalars `t`.
    pub fn expand(self, t: &[f64]) -> Vec<f64> {
        match self {
            Tie::WheelAt { layout } => {
                let h = wheel_heads(&HEAD_LAYOUTS[layout].1, t[0], t[1]);
                vec![h[0][0], h[1][0], h[2][0], h[0][1], h[1][1], h[2][1]]
            }
            Tie::CommonScale => vec![t[0]; 3],
        }
    }
    /// The tie's scalars closest (least squares) to the effect's parameters `p`: the inverse of
    /// [`Tie::expand`] on what it can describe.
    pub fn reduce(self, p: &[f64]) -> Vec<f64> {
        match self {
            Tie::WheelAt { layout } => {
                // The two per-head basis vectors are orthonormal head by head.
                let s = HEAD_LAYOUTS[layout].1.map(f64::to_radians);
                let a = (0..3).map(|i| p[i] * s[i].cos() + p[3 + i] * s[i].sin()).sum::<f64>() / 3.0;
                let b = (0..3).map(|i| p[i] * s[i].sin() - p[3 + i] * s[i].cos()).sum::<f64>() / 3.0;
                vec![a, b]
            }
            Tie::CommonScale => vec![p.iter().sum::<f64>() / p.len() as f64],
        }
    }
    /// The tie's scalars as parameters to fit.
    pub fn params(self) -> Vec<Param> {
        (0..self.names().len()).map(|index| Param { effect: self.effect(), index, tie: Some(self) }).collect()
    }
}

impl Param {
    /// The parameter's name within its effect.
    pub fn local_name(&self) -> String {
        match self.tie {
            Some(t) => t.names()[self.index].clone(),
            None => self.effect.param_names()[self.index].clone(),
        }
    }
    pub fn name(&self) -> String {
        format!("{}.{}", self.effect.name(), self.local_name())
    }
    /// (typical, upper) size in the parameter's unit, from the ranges of effects.md. The one
    /// table of effect magnitudes used for fitting and plausibility.
    fn sizes(&self) -> (f64, f64) {
        match self.effect {
            Effect::EncoderZeroOffset => (0.5, 1.0),
            Effect::LinkAngleError => (0.3, 0.5),
            Effect::InputAxisTilt => (0.2, 0.3),
            Effect::PlatformAxisError => (0.3, 0.5),
            Effect::CameraMount if self.index < 3 => (2.0, 3.0),
            Effect::CameraMount => (5.0, 12.0),
            Effect::CodeWheelEccentricity => (20.0, 30.0),
            Effect::EncoderScale => (5e-4, 1e-3),
            Effect::HingeBacklash => (0.05, 0.1),
            Effect::GravitySag => (0.05, 0.1),
            Effect::EncoderTimeOffset => (2.0, 5.0),
            Effect::MeasurementNoise => (0.01, 0.02),
        }
    }
    /// Typical size: sets the finite-difference step and the identifiability yardstick.
    pub fn scale(&self) -> f64 {
        self.sizes().0
    }
    /// The top of effects.md's typical range: beyond it a fitted size is reported with a warning.
    pub fn range_top(&self) -> f64 {
        self.sizes().1
    }
    /// Largest size still physically plausible (3x the top of the effects.md range): a fit
    /// needing more is explaining something else.
    pub fn plausible_max(&self) -> f64 {
        3.0 * self.sizes().1
    }
    /// The unit model's hard limit (a little inside it, so a clamped value still validates);
    /// a tie's scalars share their effect's limit.
    pub fn hard_limit(&self) -> f64 {
        let limits = self.effect.param_limits();
        0.999 * if self.tie.is_some() { limits[0] } else { limits[self.index] }
    }
}

/// All scalar parameters of the given effects (untied).
pub fn params_of(effects: &[Effect]) -> Vec<Param> {
    effects
        .iter()
        .flat_map(|&e| (0..e.param_names().len()).map(move |index| Param { effect: e, index, tie: None }))
        .collect()
}

/// The current values of `ps` in `unit` (a tie's scalars reduced from its effect's parameters).
pub fn get(unit: &UnitModel, ps: &[Param]) -> Vec<f64> {
    ps.iter()
        .map(|p| match p.tie {
            Some(t) => t.reduce(&unit.params(p.effect))[p.index],
            None => unit.params(p.effect)[p.index],
        })
        .collect()
}

/// Sets `ps` to `x` in `unit`, inside the feasible set: clearances cannot be negative, and no
/// value may pass the unit model's hard limits (a fit that wants to is reported, not aborted).
/// A tie sets all of its effect's parameters from its scalars.
pub fn set(unit: &mut UnitModel, ps: &[Param], x: &[f64]) {
    let feasible = |e: Effect, lim: f64, v: f64| {
        let v = if v.is_finite() { v.clamp(-lim, lim) } else { 0.0 };
        if e == Effect::HingeBacklash {
            v.max(0.0)
        } else {
            v
        }
    };
    let mut tied: Vec<(Tie, Vec<f64>)> = vec![];
    for (p, &v) in ps.iter().zip(x) {
        match p.tie {
            Some(t) => {
                if !tied.iter().any(|(u, _)| *u == t) {
                    tied.push((t, t.reduce(&unit.params(p.effect))));
                }
                let k = tied.iter().position(|(u, _)| *u == t).expect("just added");
                tied[k].1[p.index] = feasible(p.effect, p.hard_limit(), v);
            }
            None => {
                let mut cur = unit.params(p.effect);
                cur[p.index] = feasible(p.effect, p.hard_limit(), v);
                unit.set_params(p.effect, &cur).expect("length from param_names");
            }
        }
    }
    for (t, vals) in tied {
        let lim = t.effect().param_limits();
        let full: Vec<f64> =
            t.expand(&vals).iter().zip(&lim).map(|(v, l)| feasible(t.effect(), 0.999 * l, *v)).collect();
        unit.set_params(t.effect(), &full).expect("length from param_names");
    }
}

/// Options of [`fit_unit`].
#[derive(Debug, Clone)]
pub struct FitOptions {
    /// Expected 1-sigma noise per axis, used as residual weights (deg, mm).
    pub sigma_rot_deg: f64,
    pub sigma_trans_mm: f64,
    pub max_iter: usize,
    /// A parameter whose standard error exceeds this fraction of its typical size is held.
    pub ident_ratio: f64,
    /// Skip the identifiability check (fit everything asked for).
    pub fit_all: bool,
    /// Samples that enter the cost (None: all). Predictions always run over the whole dataset
    /// in acquisition order, so held-out samples still shape the motion history.
    pub mask: Option<Vec<bool>>,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions {
            sigma_rot_deg: 0.01,
            sigma_trans_mm: 0.05,
            max_iter: 40,
            ident_ratio: 0.3,
            fit_all: false,
            mask: None,
        }
    }
}

/// A parameter that was not fitted, and why.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Held {
    pub name: String,
    pub value: f64,
    pub std_error: f64,
    pub confounded_with: Vec<String>,
}

#[derive(Debug, Clone)]
pub struct FitResult {
    pub unit: UnitModel,
    pub free: Vec<Param>,
    /// Standard errors of the free parameters (same order), in their units.
    pub std_error: Vec<f64>,
    pub held: Vec<Held>,
    pub rms_rot_deg: f64,
    pub rms_trans_mm: f64,
    pub iterations: usize,
}

/// Per-sample residuals (rotation vector deg, translation mm) of a unit on a dataset.
pub fn residuals(unit: &UnitModel, data: &Dataset) -> Result<Vec<[f64; 6]>> {
    let pred = unit.compile()?.predict_dataset(data)?;
    Ok(pred.iter().zip(&data.samples).map(|(p, s)| residual6(p, &s.pose)).collect())
}

/// Residual between a predicted and a measured P: rotation vector of R_pred^T R_meas (deg)
/// and t_meas - t_pred (mm).
pub fn residual6(pred: &[f64; 6], meas: &[f64; 6]) -> [f64; 6] {
    let (a, b) = (Pose::from_p6(pred), Pose::from_p6(meas));
    let w = rotation_vector(&(a.r.transpose() * b.r)).map(f64::to_degrees);
    let d = b.t - a.t;
    [w.x, w.y, w.z, d.x, d.y, d.z]
}

/// RMS of the rotation-vector norm (deg) and of the translation norm (mm).
pub fn rms(res: &[[f64; 6]]) -> (f64, f64) {
    let n = res.len().max(1) as f64;
    let r = res.iter().map(|e| e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sum::<f64>() / n;
    let t = res.iter().map(|e| e[3] * e[3] + e[4] * e[4] + e[5] * e[5]).sum::<f64>() / n;
    (r.sqrt(), t.sqrt())
}

struct Problem<'a> {
    base: UnitModel,
    free: Vec<Param>,
    data: &'a Dataset,
    w: [f64; 2],
    mask: Option<&'a [bool]>,
}

impl Problem<'_> {
    fn unit_at(&self, x: &[f64]) -> UnitModel {
        let mut u = self.base.clone();
        set(&mut u, &self.free, x);
        u
    }

    fn resid(&self, x: &[f64]) -> Result<DVector<f64>> {
        let mut r = residuals(&self.unit_at(x), self.data)?;
        if let Some(m) = self.mask {
            r = r.into_iter().zip(m).filter(|(_, &k)| k).map(|(e, _)| e).collect();
        }
        let mut v = DVector::zeros(r.len() * 6);
        for (i, e) in r.iter().enumerate() {
            for k in 0..6 {
                v[6 * i + k] = e[k] * if k < 3 { self.w[0] } else { self.w[1] };
            }
        }
        Ok(v)
    }

    /// Forward-difference Jacobian, the parameters split over two threads.
    fn jacobian(&self, x: &[f64], r0: &DVector<f64>) -> Result<DMatrix<f64>> {
        let n = self.free.len();
        let cols: Vec<Result<DVector<f64>>> = std::thread::scope(|s| {
            let handles: Vec<_> = (0..2)
                .map(|t| {
                    s.spawn(move || {
                        (0..n)
                            .filter(|j| j % 2 == t)
                            .map(|j| {
                                // Forward step; backward where the forward one leaves the valid
                                // region (a singular pose, a hard limit, a clearance at zero).
                                let h = 1e-3 * self.free[j].scale();
                                let mut xp = x.to_vec();
                                xp[j] += h;
                                self.resid(&xp).map(|rp| (j, (rp - r0) / h)).or_else(|e| {
                                    xp[j] = x[j] - h;
                                    self.resid(&xp).map(|rm| (j, (r0 - rm) / h)).map_err(|_| e)
                                })
                            })
                            .collect::<Vec<_>>()
                    })
                })
                .collect();
            let mut out: Vec<Option<Result<DVector<f64>>>> = (0..n).map(|_| None).collect();
            for h in handles {
                for item in h.join().expect("jacobian thread") {
                    match item {
                        Ok((j, c)) => out[j] = Some(Ok(c)),
                        Err(e) => return vec![Err(e)],
                    }
                }
            }
            out.into_iter().map(|c| c.expect("every column")).collect()
        });
        let mut j = DMatrix::zeros(r0.len(), n);
        for (k, c) in cols.into_iter().enumerate() {
            j.set_column(k, &c?);
        }
        Ok(j)
    }
}

/// Standard errors (in units of noise-weighted residuals) of all columns of J.
fn std_errors(j: &DMatrix<f64>) -> Option<(DVector<f64>, DMatrix<f64>)> {
    let jtj = j.transpose() * j;
    let cov = jtj.clone().pseudo_inverse(1e-14 * jtj.diagonal().max()).ok()?;
    Some((cov.diagonal().map(|v| v.max(0.0).sqrt()), cov))
}

/// [`fit_params`]'s problem for the shared LM loop: the current point and its residuals, the
/// last linearisation (its Jacobian also gives the standard errors), one candidate step.
struct Fit<'p, 'a> {
    prob: &'p Problem<'a>,
    x: Vec<f64>,
    r: DVector<f64>,
    jac: DMatrix<f64>,
    jtj: DMatrix<f64>,
    g: DVector<f64>,
    cand: Option<(Vec<f64>, DVector<f64>)>,
}

impl LmProblem for Fit<'_, '_> {
    type Error = CalibError;

    fn linearise(&mut self) -> Result<()> {
        self.jac = self.prob.jacobian(&self.x, &self.r)?;
        self.jtj = self.jac.transpose() * &self.jac;
        self.g = self.jac.transpose() * &self.r;
        Ok(())
    }

    fn try_step(&mut self, lambda: f64) -> Result<Option<f64>> {
        let mut a = self.jtj.clone();
        for k in 0..a.nrows() {
            a[(k, k)] += lambda * self.jtj[(k, k)].max(1e-12);
        }
        let Some(step) = a.cholesky().map(|c| c.solve(&(-&self.g))) else {
            return Ok(None);
        };
        let xn: Vec<f64> = self.x.iter().zip(step.iter()).map(|(a, b)| a + b).collect();
        // A step out of the valid region (e.g. near-singular) is refused: a shorter one follows.
        let Ok(rn) = self.prob.resid(&xn) else {
            return Ok(None);
        };
        let c = rn.norm_squared();
        self.cand = Some((xn, rn));
        Ok(Some(c))
    }

    fn accept(&mut self) {
        if let Some((x, r)) = self.cand.take() {
            self.x = x;
            self.r = r;
        }
    }
}

/// Fits the parameters of `effects` (switched on if they are not) starting from `start`.
pub fn fit_unit(start: &UnitModel, effects: &[Effect], data: &Dataset, opts: &FitOptions) -> Result<FitResult> {
    fit_params(start, &params_of(effects), data, opts)
}

/// Fits the given scalar parameters (their effects switched on) starting from `start`; the
/// other parameters stay as they are in `start`.
pub fn fit_params(start: &UnitModel, params: &[Param], data: &Dataset, opts: &FitOptions) -> Result<FitResult> {
    if data.is_empty() {
        return Err(CalibError::Data("no samples to fit".into()));
    }
    let mut base = start.clone();
    for p in params {
        if !p.effect.is_kinematic() {
            return Err(CalibError::Invalid(format!("{} cannot be fitted from a static dataset", p.effect)));
        }
        base.set_enabled(p.effect, true);
    }
    let all = params.to_vec();
    let w = [1.0 / opts.sigma_rot_deg, 1.0 / opts.sigma_trans_mm];
    if let Some(m) = &opts.mask {
        if m.len() != data.len() {
            return Err(CalibError::Invalid(format!("mask of {} for {} samples", m.len(), data.len())));
        }
    }
    let mut prob = Problem { base: base.clone(), free: all.clone(), data, w, mask: opts.mask.as_deref() };
    let mut held = Vec::new();

    // Identifiability at the starting point, worst parameter out first.
    if !opts.fit_all && !prob.free.is_empty() {
        let x0 = get(&base, &prob.free);
        let r0 = prob.resid(&x0)?;
        let mut jac = prob.jacobian(&x0, &r0)?;
        while let Some((se, cov)) = std_errors(&jac) {
            let (worst, ratio) = (0..prob.free.len())
                .map(|k| (k, se[k] / prob.free[k].scale()))
                .fold((0, 0.0), |a, b| if b.1 > a.1 { b } else { a });
            if ratio <= opts.ident_ratio || prob.free.len() <= 1 && ratio.is_finite() {
                break;
            }
            // The parameters most correlated with it explain why it cannot be separated.
            let mut corr: Vec<(usize, f64)> = (0..prob.free.len())
                .filter(|&k| k != worst)
                .map(|k| (k, (cov[(worst, k)] / (se[worst] * se[k]).max(1e-300)).abs()))
                .collect();
            corr.sort_by(|a, b| b.1.total_cmp(&a.1));
            let p = prob.free[worst];
            held.push(Held {
                name: p.name(),
                value: x0[all.iter().position(|q| *q == p).unwrap()],
                std_error: se[worst],
                confounded_with: corr.iter().take(3).filter(|c| c.1 > 0.5).map(|c| prob.free[c.0].name()).collect(),
            });
            prob.free.remove(worst);
            jac = jac.remove_column(worst);
            if prob.free.is_empty() {
                break;
            }
        }
    }

    // Levenberg-Marquardt (Marquardt's diagonal scaling, factor 10 both ways): the shared loop.
    let x = get(&base, &prob.free);
    let r = prob.resid(&x)?;
    let cost0 = r.norm_squared();
    let jac = DMatrix::zeros(r.len(), prob.free.len());
    let mut fit = Fit { prob: &prob, x, r, jac, jtj: DMatrix::zeros(0, 0), g: DVector::zeros(0), cand: None };
    let max_iter = if prob.free.is_empty() { 0 } else { opts.max_iter };
    let out = levenberg_marquardt(&mut fit, cost0, max_iter, &Damping::default())?;
    let (iterations, cost) = (out.iterations, out.cost);
    let Fit { x, r, jac, .. } = fit;
    let unit = prob.unit_at(&x);
    // Standard errors at the solution, scaled by the achieved residual level.
    let dof = (r.len() as f64 - x.len() as f64).max(1.0);
    let s2 = cost / dof;
    let std_error = if x.is_empty() {
        vec![]
    } else {
        std_errors(&jac).map(|(se, _)| se.iter().map(|v| v * s2.sqrt()).collect()).unwrap_or_default()
    };
    let mut res = residuals(&unit, data)?;
    if let Some(m) = &opts.mask {
        res = res.into_iter().zip(m).filter(|(_, &k)| k).map(|(e, _)| e).collect();
    }
    let (rms_rot_deg, rms_trans_mm) = rms(&res);
    Ok(FitResult { unit, free: prob.free, std_error, held, rms_rot_deg, rms_trans_mm, iterations })
}

/// The noise-weighted residual vector r (6 per sample: rotation / sigma_rot, translation /
/// sigma_trans) of `unit` and its Jacobian with respect to `params` (finite differences).
pub fn weighted_jacobian(
    unit: &UnitModel,
    params: &[Param],
    data: &Dataset,
    sigma: (f64, f64),
) -> Result<(DMatrix<f64>, DVector<f64>)> {
    let prob =
        Problem { base: unit.clone(), free: params.to_vec(), data, w: [1.0 / sigma.0, 1.0 / sigma.1], mask: None };
    let x = get(unit, params);
    let r = prob.resid(&x)?;
    let j = prob.jacobian(&x, &r)?;
    Ok((j, r))
}

/// Effects a static dataset can reveal (everything kinematic).
pub fn static_effects() -> Vec<Effect> {
    Effect::ALL.into_iter().filter(|e| e.is_kinematic()).collect()
}
