//! The linearised design of one round: around the current fitted model, the weighted residual
//! `r` (noise units) and the columns of how the prediction moves with each parameter: the
//! model's own free parameters (the base), every candidate effect's parameters (switched on at
//! zero) and every link-angle ripple no library effect describes. Cross-validated chi-square of
//! any set of columns then costs a few small matrix solves (per-fold Gram matrices), so effects
//! can be compared jointly, in pairs and triples, instead of one at a time.
use super::structure::{drift_columns, ripple_columns};
use crate::error::Result;
use crate::identify::{params_of, weighted_jacobian, wheel_heads, Param, Tie, HEAD_LAYOUTS};
use abvs_eye::dataset::Dataset;
use abvs_eye::unit::{Effect, UnitModel};
use nalgebra::{DMatrix, DVector};
use std::ops::Range;

/// What a group of columns stands for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BlockKind {
    Base,
    Effect(Effect),
    Ripple {
        link: usize,
        cycles: usize,
    },
    /// code_wheel_eccentricity of one wheel read by heads at a known layout
    /// ([`HEAD_LAYOUTS`]): two columns, the offset's components `(e cos phi, e sin phi)` (um),
    /// the scalars of [`Tie::WheelAt`].
    Wheel {
        layout: usize,
    },
    /// encoder_scale common to the three links (one shared wheel, one pitch): one column.
    CommonScale,
    /// A drift of the measured orientation over the session (outside the library): three
    /// columns, a base-frame rotation growing linearly in time (deg at the last sample).
    Drift,
}

#[derive(Debug, Clone)]
pub struct Block {
    pub kind: BlockKind,
    pub cols: Range<usize>,
    /// The parameters behind the columns (effects and base only).
    pub params: Vec<Param>,
}

pub struct Design {
    pub blocks: Vec<Block>,
    /// Column norms (columns are stored normalised; a solution divides by them).
    norms: Vec<f64>,
    gram: Vec<DMatrix<f64>>,
    xr: Vec<DVector<f64>>,
    rr: Vec<f64>,
    gram_all: DMatrix<f64>,
    xr_all: DVector<f64>,
    rr_all: f64,
}

/// Relative ridge on normalised Gram matrices: keeps exactly collinear sets solvable.
const RIDGE: f64 = 1e-9;

impl Design {
    /// Builds the design at `unit` (its fitted state) for `free` (the base) and `candidates`.
    /// Candidates whose parameters do not move the prediction at all get an empty block.
    pub fn build(
        unit: &UnitModel,
        free: &[Param],
        candidates: &[Effect],
        data: &Dataset,
        folds: &[Vec<bool>],
        sigma: (f64, f64),
    ) -> Result<Design> {
        let n = data.len();
        let (jb, r) = weighted_jacobian(unit, free, data, sigma)?;
        let mut cols: Vec<DVector<f64>> = (0..jb.ncols()).map(|k| -jb.column(k).into_owned()).collect();
        let mut blocks = vec![Block { kind: BlockKind::Base, cols: 0..cols.len(), params: free.to_vec() }];
        for &c in candidates {
            let mut trial = unit.clone();
            let zero = vec![0.0; c.param_names().len()];
            trial.set_params(c, &zero)?;
            trial.set_enabled(c, true);
            let ps = params_of(&[c]);
            let start = cols.len();
            // A candidate that cannot even be evaluated here (e.g. a singular pose) is skipped.
            if let Ok((jc, _)) = weighted_jacobian(&trial, &ps, data, sigma) {
                for k in 0..jc.ncols() {
                    cols.push(-jc.column(k).into_owned());
                }
                blocks.push(Block { kind: BlockKind::Effect(c), cols: start..cols.len(), params: ps });
            } else {
                blocks.push(Block { kind: BlockKind::Effect(c), cols: start..start, params: vec![] });
            }
        }
        // One wheel: the per-head columns combined as the layout ties them (linear in a, b).
        if let Some(blk) = blocks.iter().find(|b| b.kind == BlockKind::Effect(Effect::CodeWheelEccentricity)).cloned() {
            if blk.cols.len() == 6 {
                for (layout, (_, at)) in HEAD_LAYOUTS.iter().enumerate() {
                    let start = cols.len();
                    for (a, b) in [(1.0, 0.0), (0.0, 1.0)] {
                        let h = wheel_heads(at, a, b);
                        let mut c = DVector::zeros(6 * n);
                        for i in 0..3 {
                            c += &cols[blk.cols.start + i] * h[i][0] + &cols[blk.cols.start + 3 + i] * h[i][1];
                        }
                        cols.push(c);
                    }
                    blocks.push(Block {
                        kind: BlockKind::Wheel { layout },
                        cols: start..cols.len(),
                        params: Tie::WheelAt { layout }.params(),
                    });
                }
            }
        }
        if let Some(blk) = blocks.iter().find(|b| b.kind == BlockKind::Effect(Effect::EncoderScale)).cloned() {
            if blk.cols.len() == 3 {
                let c = blk.cols.clone().fold(DVector::zeros(6 * n), |acc, k| acc + &cols[k]);
                cols.push(c);
                blocks.push(Block {
                    kind: BlockKind::CommonScale,
                    cols: cols.len() - 1..cols.len(),
                    params: Tie::CommonScale.params(),
                });
            }
        }
        for (link, cycles, pair) in ripple_columns(unit, data, sigma)? {
            let start = cols.len();
            cols.extend(pair);
            blocks.push(Block { kind: BlockKind::Ripple { link, cycles }, cols: start..cols.len(), params: vec![] });
        }
        if let Some(d) = drift_columns(data, sigma.0) {
            let start = cols.len();
            cols.extend(d);
            blocks.push(Block { kind: BlockKind::Drift, cols: start..cols.len(), params: vec![] });
        }
        let rows = 6 * n;
        let m = cols.len();
        let mut x = DMatrix::zeros(rows, m);
        let mut norms = vec![1.0; m];
        for (k, c) in cols.iter().enumerate() {
            let nk = c.norm();
            // A column that never moves stays zero (its parameter is invisible in these data).
            norms[k] = if nk > 1e-300 { nk } else { 1.0 };
            x.set_column(k, &(c / norms[k]));
        }
        let mut gram = vec![];
        let mut xr = vec![];
        let mut rr = vec![];
        for fold in folds {
            let idx: Vec<usize> = (0..n).filter(|&i| fold[i]).flat_map(|i| 6 * i..6 * i + 6).collect();
            let xf = x.select_rows(idx.iter());
            let rf = r.select_rows(idx.iter());
            gram.push(xf.tr_mul(&xf));
            xr.push(xf.tr_mul(&rf));
            rr.push(rf.norm_squared());
        }
        let gram_all = x.tr_mul(&x);
        let xr_all = x.tr_mul(&r);
        Ok(Design { blocks, norms, gram, xr, rr, gram_all, xr_all, rr_all: r.norm_squared() })
    }

    pub fn base(&self) -> Vec<usize> {
        self.blocks[0].cols.clone().collect()
    }

    fn solve(g: &DMatrix<f64>, b: &DVector<f64>) -> DVector<f64> {
        let mut a = g.clone();
        let scale = (0..a.nrows()).map(|k| a[(k, k)]).fold(0.0, f64::max).max(1e-300);
        for k in 0..a.nrows() {
            a[(k, k)] += RIDGE * scale + 1e-300;
        }
        match a.clone().cholesky() {
            Some(c) => c.solve(b),
            None => a.pseudo_inverse(1e-12 * scale).map(|p| p * b).unwrap_or_else(|_| DVector::zeros(b.len())),
        }
    }

    fn sub(g: &DMatrix<f64>, cols: &[usize]) -> DMatrix<f64> {
        DMatrix::from_fn(cols.len(), cols.len(), |i, j| g[(cols[i], cols[j])])
    }

    fn subv(v: &DVector<f64>, cols: &[usize]) -> DVector<f64> {
        DVector::from_fn(cols.len(), |i, _| v[cols[i]])
    }

    /// Held-out chi-square of the linearised model with these columns: each fold predicted by
    /// the least-squares fit to the other folds.
    pub fn cv_chi2(&self, cols: &[usize]) -> f64 {
        if cols.is_empty() {
            return self.rr_all;
        }
        let ga = Self::sub(&self.gram_all, cols);
        let ba = Self::subv(&self.xr_all, cols);
        let mut total = 0.0;
        for f in 0..self.gram.len() {
            let gf = Self::sub(&self.gram[f], cols);
            let bf = Self::subv(&self.xr[f], cols);
            let d = Self::solve(&(&ga - &gf), &(&ba - &bf));
            total += self.rr[f] - 2.0 * d.dot(&bf) + d.dot(&(&gf * &d));
        }
        total
    }

    /// In-sample least squares on all rows: (parameter steps in their units, chi-square).
    pub fn fit(&self, cols: &[usize]) -> (Vec<f64>, f64) {
        if cols.is_empty() {
            return (vec![], self.rr_all);
        }
        let g = Self::sub(&self.gram_all, cols);
        let b = Self::subv(&self.xr_all, cols);
        let d = Self::solve(&g, &b);
        let chi = self.rr_all - 2.0 * d.dot(&b) + d.dot(&(&g * &d));
        (cols.iter().zip(d.iter()).map(|(&c, v)| v / self.norms[c]).collect(), chi)
    }

    /// Standard errors (parameter units, at unit noise) of `cols` fitted together.
    pub fn std_errors(&self, cols: &[usize]) -> Vec<f64> {
        let g = Self::sub(&self.gram_all, cols);
        let scale = (0..g.nrows()).map(|k| g[(k, k)]).fold(0.0, f64::max).max(1e-300);
        match g.pseudo_inverse(1e-12 * scale) {
            Ok(cov) => cols.iter().enumerate().map(|(i, &c)| cov[(i, i)].max(0.0).sqrt() / self.norms[c]).collect(),
            Err(_) => vec![f64::INFINITY; cols.len()],
        }
    }

    /// Share of column `col`'s variation that the columns `others` reproduce (R^2).
    pub fn explained_share(&self, col: usize, others: &[usize]) -> f64 {
        if others.is_empty() {
            return 0.0;
        }
        let g = Self::sub(&self.gram_all, others);
        let b = DVector::from_fn(others.len(), |i, _| self.gram_all[(others[i], col)]);
        let d = Self::solve(&g, &b);
        let total = self.gram_all[(col, col)].max(1e-300);
        (d.dot(&b) / total).clamp(0.0, 1.0)
    }
}
