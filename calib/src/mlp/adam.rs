//! Adam (PyTorch's formulation, bias-corrected, with weight decay added to the gradient).

pub(super) const B1: f32 = 0.9;
pub(super) const B2: f32 = 0.999;
const EPS: f32 = 1e-8;

/// Adam moments of one layer.
pub(super) struct Moments {
    pub(super) mw: Vec<f32>,
    pub(super) vw: Vec<f32>,
    pub(super) mb: Vec<f32>,
    pub(super) vb: Vec<f32>,
}

impl Moments {
    pub(super) fn zeros(n_in: usize, n_out: usize) -> Moments {
        Moments {
            mw: vec![0f32; n_in * n_out],
            vw: vec![0f32; n_in * n_out],
            mb: vec![0f32; n_out],
            vb: vec![0f32; n_out],
        }
    }
}

/// One Adam step (PyTorch's formulation, bias-corrected).
pub(super) fn adam(p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32], step: f32, isbc2: f32, wd: f32) {
    for (((p, g), m), v) in p.iter_mut().zip(g).zip(m.iter_mut()).zip(v.iter_mut()) {
        let g = g + wd * *p;
        *m = B1 * *m + (1.0 - B1) * g;
        *v = B2 * *v + (1.0 - B2) * g * g;
        *p -= step * *m / (v.sqrt() * isbc2 + EPS);
    }
}
