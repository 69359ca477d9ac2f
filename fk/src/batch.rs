//! Batched forward pass on a flat layer list (GEMM): [`crate::net::Net::eval_batch`] and the
//! training in abvs-calib share it.
use crate::net::{normalise_row, Dense, Net, CHUNK};

// ---------------------------------------------------------------------------------------------
// Batched forward/backward on a flat layer list.

/// One layer in evaluation order (trunk, then each head).
#[derive(Debug, Clone, Copy)]
pub struct PLayer {
    /// `None`: trunk layer `idx`; `Some(h)`: layer `idx` of head `h`.
    pub head: Option<usize>,
    pub idx: usize,
    /// The flat index of the layer feeding this one; `None`: the (normalised) input.
    pub src: Option<usize>,
    pub relu: bool,
    pub depth: usize,
    /// First output column, for layers whose output is (part of) the net output.
    pub out_col: Option<usize>,
    pub n_in: usize,
    pub n_out: usize,
}

pub struct Plan {
    pub layers: Vec<PLayer>,
}

impl Plan {
    pub fn new(net: &Net) -> Plan {
        let mut layers = Vec::new();
        let t = net.trunk.len();
        for (i, l) in net.trunk.iter().enumerate() {
            let last = i + 1 == t && net.heads.is_empty();
            layers.push(PLayer {
                head: None,
                idx: i,
                src: i.checked_sub(1),
                relu: !last,
                depth: i,
                out_col: last.then_some(0),
                n_in: l.n_in,
                n_out: l.n_out,
            });
        }
        let mut col = 0;
        for (h, head) in net.heads.iter().enumerate() {
            for (i, l) in head.iter().enumerate() {
                let last = i + 1 == head.len();
                let src = if i == 0 { t.checked_sub(1) } else { Some(layers.len() - 1) };
                layers.push(PLayer {
                    head: Some(h),
                    idx: i,
                    src,
                    relu: !last,
                    depth: t + i,
                    out_col: last.then_some(col),
                    n_in: l.n_in,
                    n_out: l.n_out,
                });
                if last {
                    col += l.n_out;
                }
            }
        }
        Plan { layers }
    }

    /// (flat index, first output column) of the output layers.
    pub fn outputs(&self) -> Vec<(usize, usize)> {
        let it = self.layers.iter().enumerate();
        it.filter_map(|(i, p)| p.out_col.map(|c| (i, c))).collect()
    }

    pub fn buffers(&self, rows: usize) -> Vec<Vec<f32>> {
        self.layers.iter().map(|p| vec![0f32; rows * p.n_out]).collect()
    }
}

pub fn layer<'a>(net: &'a Net, p: &PLayer) -> &'a Dense {
    match p.head {
        None => &net.trunk[p.idx],
        Some(h) => &net.heads[h][p.idx],
    }
}

pub fn layer_mut<'a>(net: &'a mut Net, p: &PLayer) -> &'a mut Dense {
    match p.head {
        None => &mut net.trunk[p.idx],
        Some(h) => &mut net.heads[h][p.idx],
    }
}

/// `c (m x n) = a (m x k) * b^T` with `b` `n x k` row-major (i.e. `X W^T`).
pub fn gemm_abt(m: usize, k: usize, n: usize, a: &[f32], b: &[f32], c: &mut [f32]) {
    assert!(a.len() >= m * k && b.len() >= n * k && c.len() >= m * n);
    // SAFETY: the extents were checked above; C does not alias A or B (distinct borrows).
    unsafe {
        matrixmultiply::sgemm(
            m,
            k,
            n,
            1.0,
            a.as_ptr(),
            k as isize,
            1,
            b.as_ptr(),
            1,
            k as isize,
            0.0,
            c.as_mut_ptr(),
            n as isize,
            1,
        )
    }
}

/// `c (m x n) = a (m x k) * b (k x n) + beta c`, all row-major (i.e. `dX = dZ W`).
pub fn gemm_ab(m: usize, k: usize, n: usize, a: &[f32], b: &[f32], beta: f32, c: &mut [f32]) {
    assert!(a.len() >= m * k && b.len() >= k * n && c.len() >= m * n);
    // SAFETY: as in gemm_abt.
    unsafe {
        matrixmultiply::sgemm(
            m,
            k,
            n,
            1.0,
            a.as_ptr(),
            k as isize,
            1,
            b.as_ptr(),
            n as isize,
            1,
            beta,
            c.as_mut_ptr(),
            n as isize,
            1,
        )
    }
}

/// `c (m x n) = a^T b` with `a` `k x m`, `b` `k x n` row-major (i.e. `dW = dZ^T X`).
pub fn gemm_atb(m: usize, k: usize, n: usize, a: &[f32], b: &[f32], c: &mut [f32]) {
    assert!(a.len() >= k * m && b.len() >= k * n && c.len() >= m * n);
    // SAFETY: as in gemm_abt.
    unsafe {
        matrixmultiply::sgemm(
            m,
            k,
            n,
            1.0,
            a.as_ptr(),
            1,
            m as isize,
            b.as_ptr(),
            n as isize,
            1,
            0.0,
            c.as_mut_ptr(),
            n as isize,
            1,
        )
    }
}

/// Forward pass of `m` normalised rows `x` (`m x n_in`), every layer's output into `acts`.
pub fn forward(net: &Net, plan: &Plan, x: &[f32], m: usize, acts: &mut [Vec<f32>]) {
    for (l, p) in plan.layers.iter().enumerate() {
        let d = layer(net, p);
        let (before, rest) = acts.split_at_mut(l);
        let out = &mut rest[0][..m * p.n_out];
        let inp: &[f32] = match p.src {
            None => &x[..m * p.n_in],
            Some(s) => &before[s][..m * p.n_in],
        };
        gemm_abt(m, p.n_in, p.n_out, inp, &d.w, out);
        for row in out.chunks_exact_mut(p.n_out) {
            for (v, b) in row.iter_mut().zip(&d.b) {
                let z = *v + b;
                *v = if p.relu { z.max(0.0) } else { z };
            }
        }
    }
}

// The batched evaluation lives with the GEMM pass it runs, so that `net` does not import this module.
impl Net {
    /// Raw inputs -> raw outputs for many samples through GEMM (the training's forward pass).
    /// Panics if the net does not have 3 inputs and 6 outputs.
    pub fn eval_batch(&self, xs: &[[f64; 3]]) -> Vec<[f64; 6]> {
        assert!(self.n_in() == 3 && self.n_out() == 6, "eval_batch needs a 3 -> 6 net");
        let plan = Plan::new(self);
        let cap = xs.len().clamp(1, CHUNK);
        let mut acts = plan.buffers(cap);
        let mut xb = vec![0f32; cap * 3];
        let mut res = Vec::with_capacity(xs.len());
        let last = plan.outputs();
        for chunk in xs.chunks(CHUNK) {
            let m = chunk.len();
            for (dst, x) in xb.chunks_exact_mut(3).zip(chunk) {
                normalise_row(&self.input_norm, x, dst);
            }
            forward(self, &plan, &xb[..m * 3], m, &mut acts);
            for i in 0..m {
                let mut r = [0.0; 6];
                for &(l, col) in &last {
                    let k = plan.layers[l].n_out;
                    for (j, v) in acts[l][i * k..(i + 1) * k].iter().enumerate() {
                        let c = col + j;
                        r[c] = *v as f64 * self.output_norm.std[c] + self.output_norm.mean[c];
                    }
                }
                res.push(r);
            }
        }
        res
    }
}
