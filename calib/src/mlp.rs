//! The paper's networks: a plain MLP (M1) and a shared trunk with a rotation and a translation
//! branch (M2), trained with Adam on normalised data and evaluated natively.
//!
//! A [`Net`] maps raw link angles (deg) to the raw pose `[alpha, beta, gamma (deg), x, y, z
//! (mm)]`. The normalisation is part of the model ([`Net::input_norm`], [`Net::output_norm`]),
//! so callers never see normalised values. Layers are [`Dense`] (f32 weights); the trunk's
//! layers are followed by ReLU (except the trunk's last layer when there are no heads: then it
//! is the linear output); each head branches from the trunk output, has ReLU between its
//! layers and a linear last layer, and the heads' outputs are concatenated in order.
//!
//! "Depth" numbers layers along a path from the input: trunk layers `0..trunk.len()`, then
//! each head's layers continue from `trunk.len()`. Freezing the first `k` layers
//! ([`TrainConfig::frozen_layers`]) freezes by depth, so `k = net.trunk.len()` freezes exactly
//! the shared trunk (what M4 needs), and `k = 4` on a 7-layer M1 or a 4+3 M2 gives the paper's
//! m1f/m2f fine-tuning.
//!
//! Two evaluation paths: [`Net::eval`] (batch 1, stack buffers, AVX2/FMA kernels when the CPU
//! has them; this is the per-frame path) and [`Net::eval_batch`] (GEMM, the same code the
//! training uses). They agree to f32 rounding, not bit for bit.
use crate::{CalibError, Result};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Input column names (for messages).
pub const INPUT_COLUMNS: [&str; 3] = ["theta1", "theta2", "theta3"];
/// Output column names (for messages).
pub const OUTPUT_COLUMNS: [&str; 6] = ["alpha", "beta", "gamma", "x", "y", "z"];
/// The paper's 2:1 rotation:translation loss weighting for M2 ([`TrainConfig::output_weights`]).
pub const M2_OUTPUT_WEIGHTS: [f64; 6] = [2.0, 2.0, 2.0, 1.0, 1.0, 1.0];

/// Widest layer [`Net::eval`] runs on stack buffers; wider nets use a heap buffer per call.
const STACK_WIDTH: usize = 256;
/// Rows per GEMM chunk in [`Net::eval_batch`] and in the validation pass.
const CHUNK: usize = 256;

/// A fully connected layer `y = W x + b`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Dense {
    pub n_in: usize,
    pub n_out: usize,
    /// `n_out x n_in`, row-major (PyTorch's `Linear.weight` layout).
    pub w: Vec<f32>,
    pub b: Vec<f32>,
}

impl Dense {
    pub fn zeros(n_in: usize, n_out: usize) -> Dense {
        Dense { n_in, n_out, w: vec![0.0; n_in * n_out], b: vec![0.0; n_out] }
    }

    /// He-uniform weights (`U(-sqrt(6/n_in), sqrt(6/n_in))`, right for ReLU nets), zero bias.
    pub fn he_uniform(n_in: usize, n_out: usize, rng: &mut impl Rng) -> Dense {
        let bound = (6.0 / n_in as f64).sqrt() as f32;
        let mut d = Dense::zeros(n_in, n_out);
        for w in &mut d.w {
            *w = rng.gen_range(-bound..bound);
        }
        d
    }

    pub fn n_params(&self) -> usize {
        self.w.len() + self.b.len()
    }

    fn check(&self) -> std::result::Result<(), String> {
        if self.n_in == 0 || self.n_out == 0 {
            return Err(format!("empty layer {}x{}", self.n_out, self.n_in));
        }
        if self.w.len() != self.n_in * self.n_out || self.b.len() != self.n_out {
            return Err(format!(
                "layer {}x{} has {} weights and {} biases",
                self.n_out,
                self.n_in,
                self.w.len(),
                self.b.len()
            ));
        }
        if !self.w.iter().chain(&self.b).all(|v| v.is_finite()) {
            return Err("non-finite weight".into());
        }
        Ok(())
    }

    /// Batch-1 forward `y = W x + b` (+ ReLU).
    #[inline]
    fn apply(&self, x: &[f32], y: &mut [f32], relu: bool, simd: bool) {
        // These checks make the raw-pointer kernel sound even for a malformed (hand-built) Net.
        assert!(self.w.len() >= self.n_in * self.n_out && self.b.len() >= self.n_out);
        assert!(x.len() >= self.n_in && y.len() >= self.n_out);
        #[cfg(target_arch = "x86_64")]
        if simd && self.n_in >= 8 {
            // SAFETY: `simd` is only true when avx2+fma were detected; lengths checked above.
            unsafe { simd::dense(&self.w, &self.b, x, y, self.n_in, self.n_out, relu) };
            return;
        }
        let _ = simd;
        dense_scalar(self, x, y, relu);
    }
}

/// Portable kernel; the 8 independent accumulators let LLVM vectorise it without fast-math.
fn dense_scalar(l: &Dense, x: &[f32], y: &mut [f32], relu: bool) {
    let x = &x[..l.n_in];
    for ((row, yj), bj) in l.w.chunks_exact(l.n_in).zip(y.iter_mut()).zip(&l.b) {
        let mut acc = [0f32; 8];
        let (rc, xc) = (row.chunks_exact(8), x.chunks_exact(8));
        let (rr, xr) = (rc.remainder(), xc.remainder());
        for (r, xx) in rc.zip(xc) {
            for t in 0..8 {
                acc[t] += r[t] * xx[t];
            }
        }
        let mut s = *bj + acc.iter().sum::<f32>();
        for (r, xx) in rr.iter().zip(xr) {
            s += r * xx;
        }
        *yj = if relu { s.max(0.0) } else { s };
    }
}

#[cfg(target_arch = "x86_64")]
mod simd {
    use std::arch::x86_64::*;

    pub fn available() -> bool {
        is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")
    }

    #[inline]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn hsum(v: __m256) -> f32 {
        let s = _mm_add_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps(v, 1));
        let s = _mm_hadd_ps(s, s);
        _mm_cvtss_f32(_mm_hadd_ps(s, s))
    }

    /// `y = W x + b` (+ ReLU), W `n_out x n_in` row-major. Eight rows at a time share each
    /// load of x and give eight independent FMA chains (enough to hide FMA latency); the eight
    /// row sums are reduced together with a hadd tree into one vector.
    ///
    /// # Safety
    /// avx2 and fma available; `w.len() >= n_in * n_out`, `b.len() >= n_out`,
    /// `x.len() >= n_in`, `y.len() >= n_out`.
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn dense(w: &[f32], b: &[f32], x: &[f32], y: &mut [f32], n_in: usize, n_out: usize, relu: bool) {
        let k8 = n_in / 8 * 8;
        let (wp, xp) = (w.as_ptr(), x.as_ptr());
        let zero = _mm256_setzero_ps();
        let tail = |row: usize| -> f32 {
            let r = &w[row * n_in + k8..(row + 1) * n_in];
            r.iter().zip(&x[k8..n_in]).map(|(a, b)| a * b).sum()
        };
        let mut j = 0;
        while j + 8 <= n_out {
            let mut a = [zero; 8];
            let mut k = 0;
            while k < k8 {
                let xv = _mm256_loadu_ps(xp.add(k));
                for (r, ar) in a.iter_mut().enumerate() {
                    *ar = _mm256_fmadd_ps(_mm256_loadu_ps(wp.add((j + r) * n_in + k)), xv, *ar);
                }
                k += 8;
            }
            // hadd(a, b) = [a0+a1, a2+a3, b0+b1, b2+b3 | same for the upper halves].
            let s01 = _mm256_hadd_ps(a[0], a[1]);
            let s23 = _mm256_hadd_ps(a[2], a[3]);
            let s45 = _mm256_hadd_ps(a[4], a[5]);
            let s67 = _mm256_hadd_ps(a[6], a[7]);
            // [r0, r1, r2, r3 | r0', r1', r2', r3'] partial sums (lower/upper input halves).
            let s0123 = _mm256_hadd_ps(s01, s23);
            let s4567 = _mm256_hadd_ps(s45, s67);
            let lo = _mm256_permute2f128_ps(s0123, s4567, 0x20);
            let hi = _mm256_permute2f128_ps(s0123, s4567, 0x31);
            let mut s = _mm256_add_ps(lo, hi);
            if k8 < n_in {
                let t: [f32; 8] = std::array::from_fn(|r| tail(j + r));
                s = _mm256_add_ps(s, _mm256_loadu_ps(t.as_ptr()));
            }
            s = _mm256_add_ps(s, _mm256_loadu_ps(b.as_ptr().add(j)));
            if relu {
                s = _mm256_max_ps(s, zero);
            }
            _mm256_storeu_ps(y.as_mut_ptr().add(j), s);
            j += 8;
        }
        while j < n_out {
            let mut acc = zero;
            let mut k = 0;
            while k < k8 {
                let wv = _mm256_loadu_ps(wp.add(j * n_in + k));
                acc = _mm256_fmadd_ps(wv, _mm256_loadu_ps(xp.add(k)), acc);
                k += 8;
            }
            let s = hsum(acc) + tail(j) + b[j];
            y[j] = if relu { s.max(0.0) } else { s };
            j += 1;
        }
    }
}

#[cfg(not(target_arch = "x86_64"))]
mod simd {
    pub fn available() -> bool {
        false
    }
}

/// Per-column affine normalisation: `normalised = (raw - mean) / std`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Affine {
    pub mean: Vec<f64>,
    pub std: Vec<f64>,
}

impl Affine {
    pub fn identity(n: usize) -> Affine {
        Affine { mean: vec![0.0; n], std: vec![1.0; n] }
    }

    /// Per-column mean and (population) std of the first `n` columns of `rows`. The std is
    /// floored at `1e-6 * max(|mean|, 1)` so a constant column normalises to 0 instead of
    /// blowing up. No rows: the identity. Panics if a row is shorter than `n`.
    pub fn fit<R: AsRef<[f64]>>(rows: &[R], n: usize) -> Affine {
        if rows.is_empty() {
            return Affine::identity(n);
        }
        let cnt = rows.len() as f64;
        let mut mean = vec![0.0; n];
        for r in rows {
            for (m, v) in mean.iter_mut().zip(&r.as_ref()[..n]) {
                *m += v;
            }
        }
        mean.iter_mut().for_each(|m| *m /= cnt);
        // Two-pass variance: the angles' offsets would cost precision in E[x^2] - E[x]^2.
        let mut var = vec![0.0; n];
        for r in rows {
            for ((s, v), m) in var.iter_mut().zip(&r.as_ref()[..n]).zip(&mean) {
                *s += (v - m) * (v - m);
            }
        }
        let std = var.iter().zip(&mean).map(|(s, m)| (s / cnt).sqrt().max(1e-6 * m.abs().max(1.0))).collect();
        Affine { mean, std }
    }

    pub fn len(&self) -> usize {
        self.mean.len()
    }

    pub fn is_empty(&self) -> bool {
        self.mean.is_empty()
    }

    fn check(&self, what: &str, n: usize) -> std::result::Result<(), String> {
        if self.mean.len() != n || self.std.len() != n {
            return Err(format!(
                "{what} normalisation has {} means and {} stds for {n} columns",
                self.mean.len(),
                self.std.len()
            ));
        }
        let ok = self.mean.iter().all(|m| m.is_finite()) && self.std.iter().all(|s| s.is_finite() && *s != 0.0);
        if !ok {
            return Err(format!("{what} normalisation is not finite or has a zero std"));
        }
        Ok(())
    }
}

/// A trunk with optional heads (see the module doc).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Net {
    /// ReLU after every trunk layer, except after the last one when `heads` is empty (then the
    /// trunk's last layer is the linear output).
    pub trunk: Vec<Dense>,
    /// Each head: ReLU between its layers, linear last layer; outputs concatenated in order.
    pub heads: Vec<Vec<Dense>>,
    pub input_norm: Affine,
    pub output_norm: Affine,
}

impl Net {
    /// M1: `layers` Dense layers in all (paper: 7): `n_in -> hidden -> ... -> n_out`, with
    /// `n_in`/`n_out` taken from the normalisations (3 and 6 for the eye). He-uniform init.
    pub fn m1(hidden: usize, layers: usize, input_norm: Affine, output_norm: Affine, seed: u64) -> Net {
        assert!(layers >= 1 && hidden >= 1, "M1 needs at least one layer");
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let trunk = chain(input_norm.len(), hidden, output_norm.len(), layers, &mut rng);
        Net { trunk, heads: vec![], input_norm, output_norm }
    }

    /// M2: `trunk_layers` shared layers (paper: 4; may be 0), then two heads of `head_layers`
    /// (paper: 3) giving the first and the second half of the outputs (rotation, translation).
    pub fn m2(
        hidden: usize,
        trunk_layers: usize,
        head_layers: usize,
        input_norm: Affine,
        output_norm: Affine,
        seed: u64,
    ) -> Net {
        assert!(head_layers >= 1 && hidden >= 1, "M2 heads need a layer");
        let n_out = output_norm.len();
        assert_eq!(n_out % 2, 0, "M2 splits the outputs in two halves");
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let n_in = input_norm.len();
        let trunk: Vec<Dense> = (0..trunk_layers)
            .map(|i| Dense::he_uniform(if i == 0 { n_in } else { hidden }, hidden, &mut rng))
            .collect();
        let head_in = if trunk_layers == 0 { n_in } else { hidden };
        let heads = (0..2).map(|_| chain(head_in, hidden, n_out / 2, head_layers, &mut rng)).collect();
        Net { trunk, heads, input_norm, output_norm }
    }

    pub fn n_in(&self) -> usize {
        self.trunk.first().or_else(|| self.heads.first().and_then(|h| h.first())).map_or(0, |l| l.n_in)
    }

    pub fn n_out(&self) -> usize {
        if self.heads.is_empty() {
            self.trunk.last().map_or(0, |l| l.n_out)
        } else {
            self.heads.iter().map(|h| h.last().map_or(0, |l| l.n_out)).sum()
        }
    }

    /// Layers along the longest path: trunk + longest head.
    pub fn depth(&self) -> usize {
        self.trunk.len() + self.heads.iter().map(Vec::len).max().unwrap_or(0)
    }

    pub fn n_params(&self) -> usize {
        self.layers().map(|(_, l)| l.n_params()).sum()
    }

    /// All layers with their depth: trunk first, then each head in order.
    pub fn layers(&self) -> impl Iterator<Item = (usize, &Dense)> {
        let t = self.trunk.len();
        self.trunk
            .iter()
            .enumerate()
            .chain(self.heads.iter().flat_map(move |h| h.iter().enumerate().map(move |(i, l)| (t + i, l))))
    }

    /// Structural check: consistent widths, finite parameters and normalisations.
    pub fn validate(&self) -> std::result::Result<(), String> {
        if self.trunk.is_empty() && self.heads.is_empty() {
            return Err("the net has no layers".into());
        }
        if self.heads.iter().any(Vec::is_empty) {
            return Err("a head has no layers".into());
        }
        let mut width = self.n_in();
        self.input_norm.check("input", width)?;
        for (i, l) in self.trunk.iter().enumerate() {
            l.check().map_err(|e| format!("trunk layer {i}: {e}"))?;
            if l.n_in != width {
                return Err(format!("trunk layer {i} takes {} inputs, gets {width}", l.n_in));
            }
            width = l.n_out;
        }
        for (h, head) in self.heads.iter().enumerate() {
            let mut w = width;
            for (i, l) in head.iter().enumerate() {
                l.check().map_err(|e| format!("head {h} layer {i}: {e}"))?;
                if l.n_in != w {
                    return Err(format!("head {h} layer {i} takes {} inputs, gets {w}", l.n_in));
                }
                w = l.n_out;
            }
        }
        self.output_norm.check("output", self.n_out())
    }

    fn max_width(&self) -> usize {
        self.layers().map(|(_, l)| l.n_in.max(l.n_out)).max().unwrap_or(0)
    }

    /// Raw input -> raw output for one sample. No heap allocation for nets up to 256 wide.
    /// Panics if `x.len() != n_in()` or the net does not have 6 outputs.
    pub fn eval(&self, x: &[f64]) -> [f64; 6] {
        let mut out = [0.0; 6];
        self.eval_into(x, &mut out);
        out
    }

    /// [`Net::eval`] for any output width (`out.len() == n_out()`).
    pub fn eval_into(&self, x: &[f64], out: &mut [f64]) {
        assert_eq!(x.len(), self.n_in(), "input width");
        assert_eq!(out.len(), self.n_out(), "output width");
        let width = self.max_width();
        if width > STACK_WIDTH {
            let mut heap = vec![0f32; 3 * width];
            let (a, rest) = heap.split_at_mut(width);
            let (b, c) = rest.split_at_mut(width);
            return self.eval_with(x, out, [a, b, c]);
        }
        let mut bufs = [[0f32; STACK_WIDTH]; 3];
        let [a, b, c] = &mut bufs;
        self.eval_with(x, out, [a, b, c]);
    }

    fn eval_with(&self, x: &[f64], out: &mut [f64], bufs: [&mut [f32]; 3]) {
        #[cfg(target_arch = "x86_64")]
        if simd::available() {
            // SAFETY: avx2 and fma were detected.
            return unsafe { self.eval_avx2(x, out, bufs) };
        }
        self.eval_body(x, out, bufs, false)
    }

    /// The whole batch-1 pass compiled for AVX2+FMA, so the kernels inline into it.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn eval_avx2(&self, x: &[f64], out: &mut [f64], bufs: [&mut [f32]; 3]) {
        self.eval_body(x, out, bufs, true)
    }

    #[inline(always)]
    fn eval_body(&self, x: &[f64], out: &mut [f64], bufs: [&mut [f32]; 3], simd: bool) {
        let [mut cur, mut nxt, spare] = bufs;
        normalise_row(&self.input_norm, x, cur);
        let (on, n_out) = (&self.output_norm, out.len());
        // Writes normalised outputs `z` as raw values into `out[off..]`.
        let mut emit = |z: &[f32], off: usize| {
            for (j, z) in z.iter().enumerate() {
                out[off + j] = *z as f64 * on.std[off + j] + on.mean[off + j];
            }
        };
        let last = self.trunk.len().wrapping_sub(1);
        for (i, l) in self.trunk.iter().enumerate() {
            let relu = i != last || !self.heads.is_empty();
            l.apply(cur, nxt, relu, simd);
            std::mem::swap(&mut cur, &mut nxt);
        }
        if self.heads.is_empty() {
            emit(&cur[..n_out], 0);
            return;
        }
        let t: &[f32] = cur;
        let mut off = 0;
        for head in &self.heads {
            let (mut p, mut q): (&mut [f32], &mut [f32]) = (&mut *nxt, &mut *spare);
            let n = head.len();
            head[0].apply(t, p, n > 1, simd);
            for (i, l) in head.iter().enumerate().skip(1) {
                l.apply(p, q, i + 1 < n, simd);
                std::mem::swap(&mut p, &mut q);
            }
            let k = head[n - 1].n_out;
            emit(&p[..k], off);
            off += k;
        }
    }

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

/// `layers` layers `n_in -> hidden ... -> n_out`.
fn chain(n_in: usize, hidden: usize, n_out: usize, layers: usize, rng: &mut ChaCha8Rng) -> Vec<Dense> {
    (0..layers)
        .map(|i| {
            let a = if i == 0 { n_in } else { hidden };
            let b = if i + 1 == layers { n_out } else { hidden };
            Dense::he_uniform(a, b, rng)
        })
        .collect()
}

fn normalise_row(a: &Affine, raw: &[f64], dst: &mut [f32]) {
    for (((d, v), m), s) in dst.iter_mut().zip(raw).zip(&a.mean).zip(&a.std) {
        *d = ((v - m) / s) as f32;
    }
}

// ---------------------------------------------------------------------------------------------
// Batched forward/backward on a flat layer list.

/// One layer in evaluation order (trunk, then each head).
#[derive(Debug, Clone, Copy)]
struct PLayer {
    /// `None`: trunk layer `idx`; `Some(h)`: layer `idx` of head `h`.
    head: Option<usize>,
    idx: usize,
    /// The flat index of the layer feeding this one; `None`: the (normalised) input.
    src: Option<usize>,
    relu: bool,
    depth: usize,
    /// First output column, for layers whose output is (part of) the net output.
    out_col: Option<usize>,
    n_in: usize,
    n_out: usize,
}

struct Plan {
    layers: Vec<PLayer>,
}

impl Plan {
    fn new(net: &Net) -> Plan {
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
    fn outputs(&self) -> Vec<(usize, usize)> {
        let it = self.layers.iter().enumerate();
        it.filter_map(|(i, p)| p.out_col.map(|c| (i, c))).collect()
    }

    fn buffers(&self, rows: usize) -> Vec<Vec<f32>> {
        self.layers.iter().map(|p| vec![0f32; rows * p.n_out]).collect()
    }
}

fn layer<'a>(net: &'a Net, p: &PLayer) -> &'a Dense {
    match p.head {
        None => &net.trunk[p.idx],
        Some(h) => &net.heads[h][p.idx],
    }
}

fn layer_mut<'a>(net: &'a mut Net, p: &PLayer) -> &'a mut Dense {
    match p.head {
        None => &mut net.trunk[p.idx],
        Some(h) => &mut net.heads[h][p.idx],
    }
}

/// `c (m x n) = a (m x k) * b^T` with `b` `n x k` row-major (i.e. `X W^T`).
fn gemm_abt(m: usize, k: usize, n: usize, a: &[f32], b: &[f32], c: &mut [f32]) {
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
fn gemm_ab(m: usize, k: usize, n: usize, a: &[f32], b: &[f32], beta: f32, c: &mut [f32]) {
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
fn gemm_atb(m: usize, k: usize, n: usize, a: &[f32], b: &[f32], c: &mut [f32]) {
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
fn forward(net: &Net, plan: &Plan, x: &[f32], m: usize, acts: &mut [Vec<f32>]) {
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

/// Weighted normalised MSE of the outputs against `y` (`m x 6`); with `grads`, writes
/// d(loss)/d(output) into the output layers' gradient buffers.
fn loss(
    plan: &Plan,
    outs: &[(usize, usize)],
    acts: &[Vec<f32>],
    y: &[f32],
    m: usize,
    wts: &[f32; 6],
    mut grads: Option<&mut [Vec<f32>]>,
) -> f64 {
    let wsum: f32 = wts.iter().sum();
    let scale = 2.0 / (m as f32 * wsum);
    let mut total = 0.0f64;
    for &(l, col) in outs {
        let k = plan.layers[l].n_out;
        let a = &acts[l][..m * k];
        let mut g = grads.as_mut().map(|g| &mut g[l][..m * k]);
        for i in 0..m {
            let mut row = 0.0f32;
            for j in 0..k {
                let c = col + j;
                let d = a[i * k + j] - y[i * 6 + c];
                row += wts[c] * d * d;
                if let Some(g) = g.as_mut() {
                    g[i * k + j] = scale * wts[c] * d;
                }
            }
            total += row as f64;
        }
    }
    total / (m as f64 * wsum as f64)
}

/// Gradient buffers: w.r.t. each layer's output (`da`, `rows x n_out`), weights and biases.
struct Grads {
    da: Vec<Vec<f32>>,
    dw: Vec<Vec<f32>>,
    db: Vec<Vec<f32>>,
    /// Whether `da[l]` already holds a contribution in this pass (the trunk's last layer
    /// collects one from every head).
    set: Vec<bool>,
}

impl Grads {
    fn new(plan: &Plan, rows: usize) -> Grads {
        let ls = &plan.layers;
        Grads {
            da: plan.buffers(rows),
            dw: ls.iter().map(|p| vec![0f32; p.n_in * p.n_out]).collect(),
            db: ls.iter().map(|p| vec![0f32; p.n_out]).collect(),
            set: vec![false; ls.len()],
        }
    }
}

/// Backward pass for the trainable layers, given the loss gradient of the output layers in
/// `g.da` and the forward activations: fills `g.dw`/`g.db` (and clobbers `g.da`).
fn backward(net: &Net, plan: &Plan, x: &[f32], m: usize, acts: &[Vec<f32>], g: &mut Grads, trainable: &[bool]) {
    g.set.iter_mut().for_each(|s| *s = false);
    // Heads come after the trunk in the flat order, so walking it backwards reaches every
    // consumer of a layer before the layer itself. Freezing is a prefix by depth, so once a
    // layer is frozen nothing before it on its path needs gradients.
    for (l, p) in plan.layers.iter().enumerate().rev() {
        if !trainable[l] {
            continue;
        }
        let mut da = std::mem::take(&mut g.da[l]);
        let gz = &mut da[..m * p.n_out];
        if p.relu {
            // relu'(z) = [a > 0] with a = relu(z).
            for (v, a) in gz.iter_mut().zip(&acts[l]) {
                if *a <= 0.0 {
                    *v = 0.0;
                }
            }
        }
        let d = layer(net, p);
        // The input gradient only matters when the layer feeding this one is trained.
        if let Some(s) = p.src.filter(|s| trainable[*s]) {
            let beta = if g.set[s] { 1.0 } else { 0.0 };
            gemm_ab(m, p.n_out, p.n_in, gz, &d.w, beta, &mut g.da[s]);
            g.set[s] = true;
        }
        let inp: &[f32] = match p.src {
            None => &x[..m * p.n_in],
            Some(s) => &acts[s][..m * p.n_in],
        };
        gemm_atb(p.n_out, m, p.n_in, gz, inp, &mut g.dw[l]);
        let db = &mut g.db[l];
        db.iter_mut().for_each(|v| *v = 0.0);
        for row in gz.chunks_exact(p.n_out) {
            for (a, b) in db.iter_mut().zip(row) {
                *a += b;
            }
        }
        g.da[l] = da;
    }
}

/// Training hyper-parameters (defaults: the paper's).
#[derive(Debug, Clone)]
pub struct TrainConfig {
    pub lr: f64,
    pub batch: usize,
    pub max_epochs: usize,
    /// Stop after this many epochs without a validation improvement.
    pub patience: usize,
    /// Shuffling seed (initialisation has its own seed in [`Net::m1`]/[`Net::m2`]).
    pub seed: u64,
    /// Per-output loss weights in normalised space; the loss is
    /// `sum_j w_j * MSE_j / sum_j w_j`, so all-ones is the plain MSE and
    /// [`M2_OUTPUT_WEIGHTS`] is `2/3 MSE_rot + 1/3 MSE_trans` (the paper's 2:1).
    pub output_weights: [f64; 6],
    /// Freeze the first k layers by depth: trunk layers first, then the first
    /// `k - trunk.len()` layers of each head. Frozen layers are bit-identical after training.
    pub frozen_layers: usize,
    /// L2 penalty added to the gradient (torch.optim.Adam's `weight_decay`), on all parameters.
    pub weight_decay: f64,
}

impl Default for TrainConfig {
    fn default() -> Self {
        TrainConfig {
            lr: 1e-4,
            batch: 128,
            max_epochs: 1000,
            patience: 100,
            seed: 0,
            output_weights: [1.0; 6],
            frozen_layers: 0,
            weight_decay: 0.0,
        }
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct TrainReport {
    /// Epochs run (1-based numbering in `best_epoch` and `progress`).
    pub epochs: usize,
    /// The epoch whose weights were kept; 0 = the initial weights (validation never improved
    /// on them, e.g. a fine-tuning that only got worse).
    pub best_epoch: usize,
    /// The monitored loss of the kept weights: validation loss, or the epoch's mean training
    /// loss when there is no validation set.
    pub best_val_loss: f64,
    /// Mean minibatch loss of the last epoch.
    pub final_train_loss: f64,
    pub seconds: f64,
    pub stopped_early: bool,
    /// (mean training loss, validation loss or NaN) per epoch.
    pub history: Vec<(f64, f64)>,
}

const B1: f32 = 0.9;
const B2: f32 = 0.999;
const EPS: f32 = 1e-8;

/// Adam moments of one layer.
struct Moments {
    mw: Vec<f32>,
    vw: Vec<f32>,
    mb: Vec<f32>,
    vb: Vec<f32>,
}

/// One Adam step (PyTorch's formulation, bias-corrected).
fn adam(p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32], step: f32, isbc2: f32, wd: f32) {
    for (((p, g), m), v) in p.iter_mut().zip(g).zip(m.iter_mut()).zip(v.iter_mut()) {
        let g = g + wd * *p;
        *m = B1 * *m + (1.0 - B1) * g;
        *v = B2 * *v + (1.0 - B2) * g * g;
        *p -= step * *m / (v.sqrt() * isbc2 + EPS);
    }
}

/// Normalised data as f32 rows.
fn normalise_set<const N: usize>(rows: &[[f64; N]], a: &Affine) -> Vec<f32> {
    let mut out = vec![0f32; rows.len() * N];
    for (d, r) in out.chunks_exact_mut(N).zip(rows) {
        normalise_row(a, r, d);
    }
    out
}

fn check_set(what: &str, x: &[[f64; 3]], y: &[[f64; 6]]) -> Result<()> {
    if x.len() != y.len() {
        return Err(CalibError::Data(format!("{what} set: {} inputs but {} targets", x.len(), y.len())));
    }
    let bad = |i: usize, kind: &str, j: usize, name: &str, v: f64| {
        CalibError::Data(format!("{what} set sample {i}, {kind} column {j} ({name}): value {v} is not finite"))
    };
    for (i, (xr, yr)) in x.iter().zip(y).enumerate() {
        if let Some(j) = xr.iter().position(|v| !v.is_finite()) {
            return Err(bad(i, "input", j, INPUT_COLUMNS[j], xr[j]));
        }
        if let Some(j) = yr.iter().position(|v| !v.is_finite()) {
            return Err(bad(i, "target", j, OUTPUT_COLUMNS[j], yr[j]));
        }
    }
    Ok(())
}

/// Validation inputs and raw targets.
pub type ValSet<'a> = (&'a [[f64; 3]], &'a [[f64; 6]]);

/// Trains `net` in place with Adam on minibatches (see [`TrainConfig`]) and keeps the weights
/// of the best epoch by validation loss (without validation data: by mean training loss).
/// Targets are raw poses; the net's own normalisations are used (fit them with
/// [`Affine::fit`] on the training set before building the net, keep them for fine-tuning).
/// Deterministic for a given seed and net. `progress(epoch, train_loss, val_loss)` is called
/// after each epoch (val_loss NaN without validation data).
///
/// Errors: [`CalibError::Data`] for an empty set, length mismatches, non-finite values (naming
/// sample and column), batch 0; [`CalibError::Invalid`] for a malformed net or config, or a
/// diverged training (the net is then left at its best weights).
pub fn train(
    net: &mut Net,
    x: &[[f64; 3]],
    y: &[[f64; 6]],
    val: Option<ValSet<'_>>,
    cfg: &TrainConfig,
    progress: &mut dyn FnMut(usize, f64, f64),
) -> Result<TrainReport> {
    let start = Instant::now();
    if x.is_empty() {
        return Err(CalibError::Data("empty training set".into()));
    }
    if cfg.batch == 0 {
        return Err(CalibError::Data("batch size 0".into()));
    }
    check_set("training", x, y)?;
    if let Some((vx, vy)) = val {
        check_set("validation", vx, vy)?;
    }
    let val = val.filter(|(vx, _)| !vx.is_empty());
    net.validate().map_err(|e| CalibError::Invalid(format!("net: {e}")))?;
    if net.n_in() != 3 || net.n_out() != 6 {
        return Err(CalibError::Mismatch(format!(
            "training needs a 3 -> 6 net, this one is {} -> {}",
            net.n_in(),
            net.n_out()
        )));
    }
    let lr_ok = cfg.lr.is_finite() && cfg.lr > 0.0;
    let wd_ok = cfg.weight_decay.is_finite() && cfg.weight_decay >= 0.0;
    if !lr_ok || !wd_ok {
        return Err(CalibError::Invalid(format!("learning rate {} / weight decay {}", cfg.lr, cfg.weight_decay)));
    }
    let w = &cfg.output_weights;
    if w.iter().any(|v| !(v.is_finite() && *v >= 0.0)) || w.iter().sum::<f64>() <= 0.0 {
        return Err(CalibError::Invalid(format!("output weights {w:?}")));
    }
    if cfg.frozen_layers >= net.depth() {
        return Err(CalibError::Invalid(format!(
            "{} frozen layers leave nothing to train in a net of depth {}",
            cfg.frozen_layers,
            net.depth()
        )));
    }

    let plan = Plan::new(net);
    let outs = plan.outputs();
    let trainable: Vec<bool> = plan.layers.iter().map(|p| p.depth >= cfg.frozen_layers).collect();
    let wts: [f32; 6] = w.map(|v| v as f32);

    let n = x.len();
    let xn = normalise_set(x, &net.input_norm);
    let yn = normalise_set(y, &net.output_norm);
    let vset = val.map(|(vx, vy)| (normalise_set(vx, &net.input_norm), normalise_set(vy, &net.output_norm), vx.len()));

    let cap = cfg.batch.min(n).max(CHUNK);
    let mut acts = plan.buffers(cap);
    let mut g = Grads::new(&plan, cap);
    let mut mom: Vec<Moments> = plan
        .layers
        .iter()
        .map(|p| Moments {
            mw: vec![0f32; p.n_in * p.n_out],
            vw: vec![0f32; p.n_in * p.n_out],
            mb: vec![0f32; p.n_out],
            vb: vec![0f32; p.n_out],
        })
        .collect();
    let mut xb = vec![0f32; cap * 3];
    let mut yb = vec![0f32; cap * 6];

    let val_loss = |net: &Net, acts: &mut [Vec<f32>]| -> f64 {
        let Some((vx, vy, nv)) = &vset else {
            return f64::NAN;
        };
        let mut sum = 0.0;
        for start in (0..*nv).step_by(cap) {
            let m = cap.min(nv - start);
            forward(net, &plan, &vx[start * 3..(start + m) * 3], m, acts);
            sum += m as f64 * loss(&plan, &outs, acts, &vy[start * 6..(start + m) * 6], m, &wts, None);
        }
        sum / *nv as f64
    };

    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let mut order: Vec<usize> = (0..n).collect();
    let mut best = net.clone();
    let (mut best_loss, mut best_epoch) = (if vset.is_some() { val_loss(net, &mut acts) } else { f64::INFINITY }, 0);
    let mut history = Vec::new();
    let mut t = 0i32;
    let mut stopped_early = false;
    let wd = cfg.weight_decay as f32;

    for epoch in 1..=cfg.max_epochs {
        order.shuffle(&mut rng);
        let mut sum = 0.0;
        for idx in order.chunks(cfg.batch) {
            let m = idx.len();
            for (k, &i) in idx.iter().enumerate() {
                xb[k * 3..k * 3 + 3].copy_from_slice(&xn[i * 3..i * 3 + 3]);
                yb[k * 6..k * 6 + 6].copy_from_slice(&yn[i * 6..i * 6 + 6]);
            }
            forward(net, &plan, &xb[..m * 3], m, &mut acts);
            sum += m as f64 * loss(&plan, &outs, &acts, &yb[..m * 6], m, &wts, Some(&mut g.da));
            backward(net, &plan, &xb[..m * 3], m, &acts, &mut g, &trainable);
            t += 1;
            let bc1 = 1.0 - (B1 as f64).powi(t);
            let bc2 = 1.0 - (B2 as f64).powi(t);
            let step = (cfg.lr / bc1) as f32;
            let isbc2 = (1.0 / bc2.sqrt()) as f32;
            for (l, p) in plan.layers.iter().enumerate().filter(|(l, _)| trainable[*l]) {
                let d = layer_mut(net, p);
                let mo = &mut mom[l];
                adam(&mut d.w, &g.dw[l], &mut mo.mw, &mut mo.vw, step, isbc2, wd);
                adam(&mut d.b, &g.db[l], &mut mo.mb, &mut mo.vb, step, isbc2, wd);
            }
        }
        let train_loss = sum / n as f64;
        let vl = val_loss(net, &mut acts);
        history.push((train_loss, vl));
        progress(epoch, train_loss, vl);
        let monitored = if vset.is_some() { vl } else { train_loss };
        if !monitored.is_finite() || !train_loss.is_finite() {
            *net = best;
            return Err(CalibError::Invalid(format!(
                "training diverged at epoch {epoch} (loss {train_loss}); lower the learning rate \
                 (the net keeps its best weights, from epoch {best_epoch})"
            )));
        }
        if monitored < best_loss {
            best_loss = monitored;
            best_epoch = epoch;
            best.clone_from(net);
        } else if epoch - best_epoch >= cfg.patience {
            stopped_early = true;
            break;
        }
    }
    *net = best;
    Ok(TrainReport {
        epochs: history.len(),
        best_epoch,
        best_val_loss: best_loss,
        final_train_loss: history.last().map_or(f64::NAN, |h| h.0),
        seconds: start.elapsed().as_secs_f64(),
        stopped_early,
        history,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn toy() -> Net {
        Net::m2(16, 2, 3, Affine::identity(3), Affine::identity(6), 1)
    }

    #[test]
    fn simd_and_scalar_kernels_agree() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for (n_in, n_out) in [(64, 64), (13, 21), (8, 3), (64, 6), (3, 64)] {
            let l = Dense::he_uniform(n_in, n_out, &mut rng);
            let x: Vec<f32> = (0..n_in).map(|_| rng.gen_range(-1.0..1.0)).collect();
            let (mut a, mut b) = (vec![0f32; n_out], vec![0f32; n_out]);
            l.apply(&x, &mut a, false, simd::available());
            dense_scalar(&l, &x, &mut b, false);
            for (u, v) in a.iter().zip(&b) {
                assert!((u - v).abs() <= 1e-5 * (1.0 + v.abs()), "{n_in}x{n_out}: {u} vs {v}");
            }
        }
    }

    #[test]
    fn eval_matches_eval_batch() {
        let net = toy();
        let xs = [[1.0, -2.0, 0.5], [0.0, 0.3, -0.7]];
        let b = net.eval_batch(&xs);
        for (x, r) in xs.iter().zip(&b) {
            let e = net.eval(x);
            for (u, v) in e.iter().zip(r) {
                assert!((u - v).abs() <= 1e-5 * (1.0 + v.abs()), "{u} vs {v}");
            }
        }
    }

    #[test]
    fn gradients_match_finite_differences() {
        let mut net = toy();
        let x: Vec<[f64; 3]> = (0..5).map(|i| [i as f64 * 0.3 - 0.5, 0.2 + 0.1 * i as f64, -0.1 * i as f64]).collect();
        let y: Vec<[f64; 6]> = (0..5).map(|i| [0.1 * i as f64, 0.2, -0.3, 0.4, 0.0, 1.0]).collect();
        let plan = Plan::new(&net);
        let outs = plan.outputs();
        let wts = [2.0f32, 2.0, 2.0, 1.0, 1.0, 1.0];
        let xn = normalise_set(&x, &net.input_norm);
        let yn = normalise_set(&y, &net.output_norm);
        let mut acts = plan.buffers(5);
        let mut lossf = |net: &Net, g: Option<&mut Grads>| {
            forward(net, &plan, &xn, 5, &mut acts);
            let l = loss(&plan, &outs, &acts, &yn, 5, &wts, g.map(|g| &mut g.da[..]));
            (l, acts.clone())
        };
        let mut g = Grads::new(&plan, 5);
        let (_, a) = lossf(&net, Some(&mut g));
        let all = vec![true; plan.layers.len()];
        backward(&net, &plan, &xn, 5, &a, &mut g, &all);
        let h = 1e-2f32;
        for (l, p) in plan.layers.iter().enumerate() {
            for k in [0, p.n_in * p.n_out / 2 + 1] {
                let w0 = layer(&net, p).w[k];
                layer_mut(&mut net, p).w[k] = w0 + h;
                let up = lossf(&net, None).0;
                layer_mut(&mut net, p).w[k] = w0 - h;
                let down = lossf(&net, None).0;
                layer_mut(&mut net, p).w[k] = w0;
                let numeric = (up - down) / (2.0 * h as f64);
                let analytic = g.dw[l][k] as f64;
                assert!(
                    (numeric - analytic).abs() < 2e-3 * (1.0 + numeric.abs()),
                    "layer {l} w[{k}]: {numeric} vs {analytic}"
                );
            }
        }
    }
}
