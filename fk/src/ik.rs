//! Calibrated inverse kinematics: the link angles at which a calibrated [`FkModel`] (any method:
//! mh, m1, m2, m4f, hybrid, a foreign ONNX network) predicts a target camera orientation
//! `[alpha, beta, gamma]` (deg, Fick, relative to home). The translation follows from the
//! orientation (three links, three rotational degrees of freedom): it is reported, not chosen.
//!
//! # Method
//! 1. Start from the nominal IK of the target (abvs-eye's closed form, on the working-mode branch).
//! 2. Freeze the motion conditions of the move from the current state to that start
//!    ([`FkModel::freeze`]: the direction each link approaches from and the direction of the
//!    platform's motion, which the physics-based models' backlash depends on, and gravity), so
//!    the model is a smooth function of the link angles near the solution.
//! 3. Newton on `Fick(model(theta)) - target` (deg): the nominal eye's analytic Jacobian at the
//!    start, Broyden updates after each step, step halving when the residual does not fall,
//!    steps of at most 5 deg; when a step fails the Jacobian is recomputed by forward
//!    differences of the model. Where that stalls (a ReLU network's kinks can make Newton
//!    cycle between linear pieces), Levenberg-Marquardt with forward-difference Jacobians
//!    takes over; if that stalls too (a local minimum of |residual|: a poorly trained network
//!    can fold), Newton restarts from points 1-2 deg around the nominal IK, nearest first.
//! 4. Evaluate the model exactly as the move will happen (the stream state advanced by the
//!    solution); if the conditions changed (another approach direction, another platform motion
//!    direction) and the residual is above the tolerance, freeze them at the solution and go
//!    back to 3 (at most three rounds).
//!
//! The solution stays continuous with the working mode: Newton walks from the nominal
//! working-mode solution in bounded steps, the physics-based models refuse any other assembly
//! mode inside their FK, and a solution farther than [`IkConfig::max_from_nominal_deg`] from the
//! nominal IK is refused.
//!
//! # Refusals ([`CalibError::Unreachable`])
//! - the target has no nominal IK or is near a nominal singularity (nothing to start from);
//! - no convergence: the best residual stays above [`IkConfig::max_residual_deg`];
//! - near-singular: the model's Jacobian d(Fick)/d(theta) has an inverse condition number below
//!   [`IkConfig::min_conditioning`], or (network models) the nominal mechanism's singularity
//!   measure at the solution is below its limit (physics-based models check their own geometry);
//! - the solution left the working mode's neighbourhood (see above).
use crate::error::{FkError as CalibError, Result};
use crate::model::{FkModel, FkState, Frozen};
use abvs_eye::encoder::deg_to_counts;
use abvs_eye::pose::rotation_vector;
use abvs_eye::{Fick, SpmGeometry};
use nalgebra::{Matrix3, Vector3};

/// How far (deg) past the training range a target is still inside the calibrated workspace.
pub const WORKSPACE_MARGIN_DEG: f64 = 0.5;

/// A target outside a model's calibrated workspace (the training data's range of each Fick angle, recorded in
/// the manifest: `training.range_deg`), where the model extrapolates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OutsideWorkspace {
    /// The first Fick angle outside: "alpha", "beta" or "gamma".
    pub axis: &'static str,
    /// Its target value (deg).
    pub value_deg: f64,
    /// Its training range (deg).
    pub range_deg: [f64; 2],
}

/// Whether target `t` (Fick deg) lies outside the training `range` by more than [`WORKSPACE_MARGIN_DEG`].
pub fn outside_workspace(range: &[[f64; 2]; 3], t: [f64; 3]) -> Option<OutsideWorkspace> {
    let names = ["alpha", "beta", "gamma"];
    (0..3)
        .find(|&k| t[k] < range[k][0] - WORKSPACE_MARGIN_DEG || t[k] > range[k][1] + WORKSPACE_MARGIN_DEG)
        .map(|k| OutsideWorkspace { axis: names[k], value_deg: t[k], range_deg: range[k] })
}

/// Solver settings.
#[derive(Debug, Clone)]
pub struct IkConfig {
    /// Converged when every Fick-angle residual is below this (deg; float32 networks: at least
    /// 2e-4). One encoder count is 0.0039 deg.
    pub tol_deg: f64,
    /// Model evaluations per Newton run at most (the Levenberg-Marquardt fallback: 4x).
    pub max_iter: usize,
    /// Refuse when the residual stays above this (deg).
    pub max_residual_deg: f64,
    /// Refuse solutions farther than this from the nominal IK on any link (deg): the model
    /// would be extrapolating far outside its data, or the solver left the working mode.
    pub max_from_nominal_deg: f64,
    /// Refuse when the model's Jacobian d(Fick)/d(theta) has sigma_min / sigma_max below this.
    /// Over the paper's workspace the nominal eye stays above 0.15.
    pub min_conditioning: f64,
    /// Largest Newton step on any link (deg).
    pub max_step_deg: f64,
}

impl Default for IkConfig {
    fn default() -> Self {
        IkConfig {
            tol_deg: 1e-5,
            max_iter: 40,
            max_residual_deg: 1e-3,
            max_from_nominal_deg: 20.0,
            min_conditioning: 0.05,
            max_step_deg: 5.0,
        }
    }
}

/// One solved target.
#[derive(Debug, Clone, PartialEq)]
pub struct IkSolution {
    /// The target orientation (deg).
    pub target_deg: [f64; 3],
    /// Link angles (deg, homed encoder readings).
    pub theta_deg: [f64; 3],
    /// The model's pose at `theta_deg` after the move from the state it was solved from
    /// (deg, mm): the orientation is the target up to `residual_deg`, the translation follows.
    pub pose: [f64; 6],
    /// Angle between the predicted and the target orientation (deg).
    pub residual_deg: f64,
    /// Where Newton started: the nominal IK of the target (deg).
    pub nominal_theta_deg: [f64; 3],
    /// sigma_min / sigma_max of the model's d(Fick)/d(theta) at the solution (from the solver's
    /// Broyden estimate; from forward differences when that is below the refusal limit).
    pub conditioning: f64,
    /// Model evaluations spent.
    pub evaluations: usize,
}

impl IkSolution {
    /// Homed encoder counts of the link angles (92672 per revolution, nearest count).
    pub fn counts(&self) -> [i64; 3] {
        self.theta_deg.map(|t| deg_to_counts(t, 0))
    }
}

/// Calibrated IK for one model; see the module doc.
pub struct CalibratedIk<'m> {
    model: &'m FkModel,
    nominal: SpmGeometry,
    pub cfg: IkConfig,
    /// Forward-difference step (deg).
    h: f64,
    tol: f64,
}

/// Step (deg) of the central differences that measure a network model's conditioning: a ReLU
/// network is piecewise linear, and a step smaller than its pieces measures one piece (at home
/// a degenerate one of an m2 network), not the map the solver moves on.
const NET_CONDITIONING_STEP_DEG: f64 = 0.25;

/// Offsets (deg) of the restarts around the nominal IK, nearest first: 1 and 2 deg along each
/// link, then the corners of the 1 deg cube.
fn restarts() -> impl Iterator<Item = Vector3<f64>> {
    let axial = [1.0, 2.0].into_iter().flat_map(|m| {
        (0..3).flat_map(move |k| {
            [-m, m].map(|v| {
                let mut d = Vector3::zeros();
                d[k] = v;
                d
            })
        })
    });
    let corners = (0..8).map(|c| Vector3::new(sgn(c & 1), sgn(c & 2), sgn(c & 4)));
    let mut all: Vec<Vector3<f64>> = axial.chain(corners).collect();
    all.sort_by(|a, b| a.norm().total_cmp(&b.norm()));
    all.into_iter()
}

fn sgn(bit: usize) -> f64 {
    if bit != 0 {
        1.0
    } else {
        -1.0
    }
}

fn wrap180(d: f64) -> f64 {
    let x = (d + 180.0).rem_euclid(360.0) - 180.0;
    if x == -180.0 {
        180.0
    } else {
        x
    }
}

fn arr(v: &Vector3<f64>) -> [f64; 3] {
    [v.x, v.y, v.z]
}

impl<'m> CalibratedIk<'m> {
    pub fn new(model: &'m FkModel) -> Self {
        Self::with_config(model, IkConfig::default())
    }

    pub fn with_config(model: &'m FkModel, cfg: IkConfig) -> Self {
        let f32 = model.runs_in_float32();
        let tol = if f32 { cfg.tol_deg.max(2e-4) } else { cfg.tol_deg };
        CalibratedIk { model, nominal: SpmGeometry::nominal(), h: if f32 { 1e-2 } else { 1e-4 }, tol, cfg }
    }

    pub fn model(&self) -> &FkModel {
        self.model
    }

    /// Link angles for `target_deg` reached from the state `st` (the motion history so far;
    /// `model.state()` at home), with gravity `gravity` in B. `st` is not advanced.
    pub fn solve(&self, st: &FkState, target_deg: [f64; 3], gravity: [f64; 3]) -> Result<IkSolution> {
        self.solve_inner(st, target_deg, gravity).map(|(s, _)| s)
    }

    /// As [`CalibratedIk::solve`], then advances `st` by the move to the solution (on success).
    pub fn solve_and_move(&self, st: &mut FkState, target_deg: [f64; 3], gravity: [f64; 3]) -> Result<IkSolution> {
        let (s, next) = self.solve_inner(st, target_deg, gravity)?;
        *st = next;
        Ok(s)
    }

    /// Targets visited in order from home, each reached from the previous solution (a refused
    /// target leaves the links where they were). `gravity`: one per target, or one for all
    /// (empty: head upright).
    pub fn solve_batch(&self, targets: &[[f64; 3]], gravity: &[[f64; 3]]) -> Vec<Result<IkSolution>> {
        let mut st = self.model.state();
        targets
            .iter()
            .enumerate()
            .map(|(k, t)| {
                let g = match gravity.len() {
                    0 => [0.0, 1.0, 0.0],
                    1 => gravity[0],
                    _ => gravity[k.min(gravity.len() - 1)],
                };
                self.solve_and_move(&mut st, *t, g)
            })
            .collect()
    }

    fn residual(&self, fr: &mut Frozen, th: &Vector3<f64>, t: &[f64; 3], evals: &mut usize) -> Result<Vector3<f64>> {
        *evals += 1;
        let p = self.model.eval_frozen(fr, &arr(th))?;
        Ok(Vector3::new(wrap180(p[0] - t[0]), wrap180(p[1] - t[1]), wrap180(p[2] - t[2])))
    }

    fn jacobian(
        &self,
        fr: &mut Frozen,
        th: &Vector3<f64>,
        f0: &Vector3<f64>,
        t: &[f64; 3],
        evals: &mut usize,
    ) -> Result<Matrix3<f64>> {
        let mut j = Matrix3::zeros();
        for k in 0..3 {
            let mut tp = *th;
            tp[k] += self.h;
            let fk = self.residual(fr, &tp, t, evals)?;
            j.set_column(k, &((fk - f0) / self.h));
        }
        Ok(j)
    }

    /// Central-difference d(Fick)/d(theta) with step `h` (deg).
    fn central_jacobian(
        &self,
        fr: &mut Frozen,
        th: &Vector3<f64>,
        t: &[f64; 3],
        h: f64,
        evals: &mut usize,
    ) -> Result<Matrix3<f64>> {
        let mut j = Matrix3::zeros();
        for k in 0..3 {
            let (mut tp, mut tm) = (*th, *th);
            tp[k] += h;
            tm[k] -= h;
            let d = self.residual(fr, &tp, t, evals)? - self.residual(fr, &tm, t, evals)?;
            j.set_column(k, &(d / (2.0 * h)));
        }
        Ok(j)
    }

    /// d(Fick angles)/d(theta) of the nominal eye at orientation `r` and link angles `th_deg`
    /// (deg per deg): the FK's angular-velocity Jacobian mapped to Fick rates.
    fn nominal_jacobian(&self, r: &Matrix3<f64>, th_deg: &[f64; 3]) -> Option<Matrix3<f64>> {
        let jw = self.nominal.fk_jacobian(r, &th_deg.map(f64::to_radians)).ok()?;
        let f = Fick::from_matrix(r);
        let (sa, ca) = f.alpha.sin_cos();
        let (sg, cg) = f.gamma.sin_cos();
        // omega = E [alpha', beta', gamma']: R = Ry(g) Rx(a) Rz(b).
        let e = Matrix3::new(cg, ca * sg, 0.0, 0.0, -sa, 1.0, -sg, ca * cg, 0.0);
        Some(e.try_inverse()? * jw)
    }

    /// Newton-Broyden under frozen conditions; returns the final residual vector.
    fn newton(
        &self,
        fr: &mut Frozen,
        th: &mut Vector3<f64>,
        t: &[f64; 3],
        jac: &mut Option<Matrix3<f64>>,
        evals: &mut usize,
    ) -> Result<Vector3<f64>> {
        let mut f = self.residual(fr, th, t, evals)?;
        let mut fresh = false;
        let mut j = match jac {
            Some(j) => *j,
            None => {
                fresh = true;
                self.jacobian(fr, th, &f, t, evals)?
            }
        };
        let start = *evals;
        while f.amax() >= self.tol && *evals - start < self.cfg.max_iter {
            let step = j.lu().solve(&(-f)).filter(|s| s.iter().all(|x| x.is_finite()));
            let accepted = match step {
                None => None,
                Some(mut s) => {
                    let m = s.amax();
                    if m > self.cfg.max_step_deg {
                        s *= self.cfg.max_step_deg / m;
                    }
                    let mut lambda = 1.0;
                    let mut acc = None;
                    for _ in 0..6 {
                        let tn = *th + s * lambda;
                        if let Ok(fnew) = self.residual(fr, &tn, t, evals) {
                            if fnew.norm() < f.norm() {
                                acc = Some((tn, fnew));
                                break;
                            }
                        }
                        lambda *= 0.5;
                    }
                    acc
                }
            };
            match accepted {
                Some((tn, fnew)) => {
                    let ds = tn - *th;
                    let y = fnew - f;
                    j += (y - j * ds) * ds.transpose() / ds.norm_squared();
                    *th = tn;
                    f = fnew;
                    fresh = false;
                }
                None if !fresh => {
                    f = self.residual(fr, th, t, evals)?;
                    j = self.jacobian(fr, th, &f, t, evals)?;
                    fresh = true;
                }
                None => break,
            }
        }
        if f.amax() >= self.tol {
            self.levenberg(fr, th, t, evals, &mut f, &mut j)?;
        }
        *jac = Some(j);
        Ok(f)
    }

    /// Levenberg-Marquardt with forward-difference Jacobians: the fallback where Newton-Broyden
    /// stalls (at the kinks of a ReLU network it can cycle between linear pieces).
    fn levenberg(
        &self,
        fr: &mut Frozen,
        th: &mut Vector3<f64>,
        t: &[f64; 3],
        evals: &mut usize,
        f: &mut Vector3<f64>,
        j: &mut Matrix3<f64>,
    ) -> Result<()> {
        let mut lambda = 1e-3;
        let start = *evals;
        while f.amax() >= self.tol && *evals - start < 4 * self.cfg.max_iter {
            *f = self.residual(fr, th, t, evals)?;
            *j = self.jacobian(fr, th, f, t, evals)?;
            let (jtj, g) = (j.transpose() * *j, j.transpose() * *f);
            let mut improved = false;
            for _ in 0..12 {
                let a = jtj + Matrix3::from_diagonal(&jtj.diagonal()) * lambda + Matrix3::identity() * 1e-12;
                if let Some(mut s) = a.lu().solve(&(-g)).filter(|s| s.iter().all(|x| x.is_finite())) {
                    let m = s.amax();
                    if m > self.cfg.max_step_deg {
                        s *= self.cfg.max_step_deg / m;
                    }
                    let tn = *th + s;
                    if let Ok(fnew) = self.residual(fr, &tn, t, evals) {
                        if fnew.norm() < f.norm() {
                            *th = tn;
                            *f = fnew;
                            lambda = (lambda / 3.0).max(1e-9);
                            improved = true;
                            break;
                        }
                    }
                }
                lambda *= 4.0;
            }
            if !improved {
                break;
            }
        }
        Ok(())
    }

    /// As [`CalibratedIk::solve`], also returning the state advanced by the move (to commit it
    /// later, e.g. once both eyes of a fixation are solved).
    pub fn solve_with_next(&self, st: &FkState, target: [f64; 3], gravity: [f64; 3]) -> Result<(IkSolution, FkState)> {
        self.solve_inner(st, target, gravity)
    }

    fn solve_inner(&self, st: &FkState, target: [f64; 3], gravity: [f64; 3]) -> Result<(IkSolution, FkState)> {
        let refuse = |why: String| CalibError::Unreachable { target_deg: target, why };
        if !target.iter().all(|v| v.is_finite()) {
            return Err(refuse("not a finite orientation".into()));
        }
        let r_t = Fick::from_deg(target).to_matrix();
        let th_nom = self
            .nominal
            .ik_checked(&r_t)
            .map_err(|e| refuse(format!("no nominal IK to start from (unreachable or near-singular): {e}")))?
            .map(f64::to_degrees);
        let mut th = Vector3::from(th_nom);
        // The nominal platform sits at the target at th_nom: a start for the model's Newton.
        let mut near = r_t;
        // The nominal eye's Jacobian at the start: Broyden corrects it towards the model's.
        let mut jac = self.nominal_jacobian(&r_t, &th_nom);
        let mut evals = 0;
        let mut out = None;
        for round in 0..3 {
            let mut fr = self
                .model
                .freeze(st, &arr(&th), gravity, Some(&near))
                .map_err(|e| refuse(format!("the model cannot evaluate theta {:?} deg: {e}", arr(&th))))?;
            evals += 1;
            let mut f = self
                .newton(&mut fr, &mut th, &target, &mut jac, &mut evals)
                .map_err(|e| refuse(format!("the model cannot evaluate theta {:?} deg on the way: {e}", arr(&th))))?;
            if round == 0 && f.amax() >= self.tol {
                // Stuck in a local minimum of |residual| (a poorly trained network folds):
                // restart from starts around the nominal IK, nearest first, and keep the first
                // that converges (the solution nearest the working-mode start).
                for d in restarts() {
                    let mut th2 = Vector3::from(th_nom) + d;
                    let mut jac2 = self.nominal_jacobian(&r_t, &th_nom);
                    if let Ok(f2) = self.newton(&mut fr, &mut th2, &target, &mut jac2, &mut evals) {
                        if f2.amax() < f.amax() {
                            (th, f, jac) = (th2, f2, jac2);
                        }
                        if f.amax() < self.tol {
                            break;
                        }
                    }
                }
            }
            // The move as it will happen: the state advanced by the solution.
            let mut next = st.clone();
            evals += 1;
            let pose = self
                .model
                .eval_near(&mut next, &arr(&th), gravity, &fr)
                .map_err(|e| refuse(format!("the model cannot evaluate the solution {:?} deg: {e}", arr(&th))))?;
            let exact =
                Vector3::new(wrap180(pose[0] - target[0]), wrap180(pose[1] - target[1]), wrap180(pose[2] - target[2]));
            let done = exact.amax() < self.tol || round == 2 || (exact - f).amax() < 0.5 * self.tol;
            out = Some((pose, exact, next, fr.clone()));
            near = fr.warm();
            if done {
                break;
            }
        }
        let (pose, exact, next, mut fr) = out.expect("at least one round");
        let theta_deg = arr(&th);
        if exact.amax() > self.cfg.max_residual_deg {
            return Err(refuse(format!(
                "no convergence: residual {:.2e} deg at theta {:?} deg after {evals} model evaluations \
                 (the model does not reach this orientation near the working mode)",
                exact.amax(),
                theta_deg
            )));
        }
        let far = (0..3).map(|i| (theta_deg[i] - th_nom[i]).abs()).fold(0.0, f64::max);
        if far > self.cfg.max_from_nominal_deg {
            return Err(refuse(format!(
                "solution {theta_deg:?} deg is {far:.1} deg from the nominal IK {th_nom:?} deg (limit {} deg): \
                 outside the working mode's neighbourhood",
                self.cfg.max_from_nominal_deg
            )));
        }
        let cond = |j: &Matrix3<f64>| {
            let sv = j.singular_values();
            if sv.max() > 0.0 {
                sv.min() / sv.max()
            } else {
                0.0
            }
        };
        // The Broyden Jacobian is an estimate: below the limit, differentiate the model itself.
        let mut conditioning = cond(&jac.expect("Jacobian"));
        if conditioning < self.cfg.min_conditioning {
            let th = Vector3::from(theta_deg);
            let fd = if self.model.unit().is_some() {
                self.residual(&mut fr, &th, &target, &mut evals)
                    .and_then(|f| self.jacobian(&mut fr, &th, &f, &target, &mut evals))
            } else {
                self.central_jacobian(&mut fr, &th, &target, NET_CONDITIONING_STEP_DEG, &mut evals)
            };
            conditioning = fd.map(|j| cond(&j)).unwrap_or(0.0);
        }
        if conditioning < self.cfg.min_conditioning {
            return Err(refuse(format!(
                "near-singular: the model's d(orientation)/d(theta) has inverse condition number {conditioning:.4} \
                 at theta {theta_deg:?} deg (limit {})",
                self.cfg.min_conditioning
            )));
        }
        if self.model.unit().is_none() {
            let th_rad = theta_deg.map(f64::to_radians);
            let sol = self
                .nominal
                .fk_from(&th_rad, &r_t)
                .or_else(|_| self.nominal.fk_cold(&th_rad))
                .map_err(|e| refuse(format!("near-singular: {e}")))?;
            self.nominal.check_singularity(&sol.r, &th_rad).map_err(|e| refuse(format!("near-singular: {e}")))?;
        }
        let r_p = Fick::from_deg([pose[0], pose[1], pose[2]]).to_matrix();
        let residual_deg = rotation_vector(&(r_p.transpose() * r_t)).norm().to_degrees();
        Ok((
            IkSolution {
                target_deg: target,
                theta_deg,
                pose,
                residual_deg,
                nominal_theta_deg: th_nom,
                conditioning,
                evaluations: evals,
            },
            next,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_target_past_the_training_range_and_its_margin_is_outside() {
        let r = [[-30.0, 30.0], [-15.0, 15.0], [-30.0, 30.0]];
        assert_eq!(outside_workspace(&r, [30.4, -15.4, 0.0]), None);
        let o = outside_workspace(&r, [0.0, 15.6, 40.0]).unwrap();
        assert_eq!(o, OutsideWorkspace { axis: "beta", value_deg: 15.6, range_deg: [-15.0, 15.0] });
    }

    #[test]
    fn nominal_conditioning_over_the_workspace() {
        // The refusal limit sits well below what the nominal eye shows over the paper's workspace.
        let m = crate::model::FkModel::load(std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../fixtures/session/calib/eye0"
        )))
        .unwrap();
        let ik = CalibratedIk::new(&m);
        let mut worst: f64 = 1.0;
        for a in abvs_eye::psc::grid(-30.0, 30.0, 5.0) {
            for b in abvs_eye::psc::grid(-15.0, 15.0, 5.0) {
                for c in abvs_eye::psc::grid(-30.0, 30.0, 5.0) {
                    let r = Fick::from_deg([a, b, c]).to_matrix();
                    let th = ik.nominal.ik(&r).unwrap().map(f64::to_degrees);
                    let sv = ik.nominal_jacobian(&r, &th).unwrap().singular_values();
                    worst = worst.min(sv.min() / sv.max());
                }
            }
        }
        println!("nominal d(Fick)/d(theta) conditioning over the workspace >= {worst:.3}");
        assert!(worst > 3.0 * IkConfig::default().min_conditioning, "{worst}");
    }

    #[test]
    fn wrap180_range() {
        assert_eq!(wrap180(190.0), -170.0);
        assert_eq!(wrap180(-180.0), 180.0);
        assert!((wrap180(-359.5) - 0.5).abs() < 1e-12);
    }
}
