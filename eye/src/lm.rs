//! The one Levenberg-Marquardt loop of abvs: FK calibration (abvs-calib's `identify`) and
//! camera-pose bundle adjustment (abvs-camcal's `measure`) both run it. A problem supplies the
//! linearisation and the damped step (dense Cholesky there, a Schur complement here); the loop
//! owns the damping schedule, acceptance and stopping, so the two cannot drift apart again.
//! It lives in abvs-eye because that is the lowest crate both calibrations build on.

/// The damping schedule. The defaults are Marquardt's factor of 10 both ways.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Damping {
    /// Starting lambda.
    pub initial: f64,
    /// Factor on lambda after a step that did not lower the cost.
    pub increase: f64,
    /// Factor on lambda when the damped system could not be solved or the step left the valid
    /// region.
    pub increase_unsolvable: f64,
    /// Divisor of lambda after an accepted step (not below `floor`).
    pub decrease: f64,
    pub floor: f64,
    /// Damped steps tried per linearisation before giving up.
    pub tries: usize,
}

impl Default for Damping {
    fn default() -> Self {
        Damping { initial: 1e-3, increase: 10.0, increase_unsolvable: 10.0, decrease: 10.0, floor: 1e-12, tries: 10 }
    }
}

/// What [`levenberg_marquardt`] asks of a least-squares problem. The problem holds its current
/// point and one candidate.
pub trait LmProblem {
    type Error;
    /// Linearises at the current point (Jacobian, normal equations).
    fn linearise(&mut self) -> Result<(), Self::Error>;
    /// Solves the system damped by `lambda` from the last linearisation and evaluates the
    /// candidate point: its cost, or `None` when no step could be taken (singular system,
    /// candidate outside the model's valid region). An error ends the solve.
    fn try_step(&mut self, lambda: f64) -> Result<Option<f64>, Self::Error>;
    /// Makes the last candidate the current point.
    fn accept(&mut self);
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LmOutcome {
    /// Linearisations done.
    pub iterations: usize,
    /// Cost at the returned point.
    pub cost: f64,
}

/// Minimises from the problem's current point of cost `cost`: at most `max_iter`
/// linearisations; stops when no damped step lowers the cost or an accepted step lowers it by
/// less than 1e-12 relative.
pub fn levenberg_marquardt<P: LmProblem>(
    p: &mut P,
    mut cost: f64,
    max_iter: usize,
    d: &Damping,
) -> Result<LmOutcome, P::Error> {
    let mut lambda = d.initial;
    let mut iterations = 0;
    while iterations < max_iter {
        iterations += 1;
        p.linearise()?;
        let mut improved = false;
        for _ in 0..d.tries {
            let Some(c) = p.try_step(lambda)? else {
                lambda *= d.increase_unsolvable;
                continue;
            };
            if c < cost {
                let rel = (cost - c) / cost.max(1e-300);
                p.accept();
                cost = c;
                lambda = (lambda / d.decrease).max(d.floor);
                improved = rel >= 1e-12;
                break;
            }
            lambda *= d.increase;
        }
        if !improved {
            break;
        }
    }
    Ok(LmOutcome { iterations, cost })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rosenbrock as residuals r = [10 (y - x^2), 1 - x], dense 2x2 normal equations.
    struct Rosen {
        x: [f64; 2],
        cand: [f64; 2],
        jtj: [[f64; 2]; 2],
        g: [f64; 2],
    }

    fn r(x: &[f64; 2]) -> [f64; 2] {
        [10.0 * (x[1] - x[0] * x[0]), 1.0 - x[0]]
    }

    fn cost(x: &[f64; 2]) -> f64 {
        let r = r(x);
        r[0] * r[0] + r[1] * r[1]
    }

    impl LmProblem for Rosen {
        type Error = ();
        fn linearise(&mut self) -> Result<(), ()> {
            let j = [[-20.0 * self.x[0], 10.0], [-1.0, 0.0]];
            let rv = r(&self.x);
            for a in 0..2 {
                self.g[a] = j[0][a] * rv[0] + j[1][a] * rv[1];
                for b in 0..2 {
                    self.jtj[a][b] = j[0][a] * j[0][b] + j[1][a] * j[1][b];
                }
            }
            Ok(())
        }
        fn try_step(&mut self, lambda: f64) -> Result<Option<f64>, ()> {
            let mut a = self.jtj;
            for k in 0..2 {
                a[k][k] += lambda * self.jtj[k][k].max(1e-12);
            }
            let det = a[0][0] * a[1][1] - a[0][1] * a[1][0];
            if det.abs() < 1e-300 {
                return Ok(None);
            }
            let s0 = -(a[1][1] * self.g[0] - a[0][1] * self.g[1]) / det;
            let s1 = -(-a[1][0] * self.g[0] + a[0][0] * self.g[1]) / det;
            self.cand = [self.x[0] + s0, self.x[1] + s1];
            Ok(Some(cost(&self.cand)))
        }
        fn accept(&mut self) {
            self.x = self.cand;
        }
    }

    #[test]
    fn solves_rosenbrock_and_counts_linearisations() {
        let mut p = Rosen { x: [-1.2, 1.0], cand: [0.0; 2], jtj: [[0.0; 2]; 2], g: [0.0; 2] };
        let c0 = cost(&p.x);
        let out = levenberg_marquardt(&mut p, c0, 200, &Damping::default()).unwrap();
        assert!((p.x[0] - 1.0).abs() < 1e-6 && (p.x[1] - 1.0).abs() < 1e-6, "{:?}", p.x);
        assert!(out.cost < 1e-12 && out.iterations > 1 && out.iterations < 200, "{out:?}");
        // No iterations allowed: nothing is linearised and the point stays.
        let mut q = Rosen { x: [-1.2, 1.0], cand: [0.0; 2], jtj: [[0.0; 2]; 2], g: [0.0; 2] };
        assert_eq!(levenberg_marquardt(&mut q, c0, 0, &Damping::default()).unwrap().iterations, 0);
        assert_eq!(q.x, [-1.2, 1.0]);
    }
}
