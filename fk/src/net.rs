//! The paper's networks: a plain MLP (M1) and a shared trunk with a rotation and a translation
//! branch (M2), evaluated natively (their training lives in abvs-calib's `mlp`).
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
//! (`TrainConfig::frozen_layers`) freezes by depth, so `k = net.trunk.len()` freezes exactly
//! the shared trunk (what M4 needs), and `k = 4` on a 7-layer M1 or a 4+3 M2 gives the paper's
//! m1f/m2f fine-tuning.
//!
//! Two evaluation paths: [`Net::eval`] (batch 1, stack buffers, AVX2/FMA kernels when the CPU
//! has them; this is the per-frame path) and [`Net::eval_batch`] (GEMM, the same code the
//! training uses). They agree to f32 rounding, not bit for bit.
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Input column names (for messages).
pub const INPUT_COLUMNS: [&str; 3] = ["theta1", "theta2", "theta3"];
/// Output column names (for messages).
pub const OUTPUT_COLUMNS: [&str; 6] = ["alpha", "beta", "gamma", "x", "y", "z"];
/// The paper's 2:1 rotation:translation loss weighting for M2 (`TrainConfig::output_weights`).
pub const M2_OUTPUT_WEIGHTS: [f64; 6] = [2.0, 2.0, 2.0, 1.0, 1.0, 1.0];

/// Widest layer [`Net::eval`] runs on stack buffers; wider nets use a heap buffer per call.
const STACK_WIDTH: usize = 256;
/// Rows per GEMM chunk in [`Net::eval_batch`] and in the validation pass.
pub const CHUNK: usize = 256;

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

/// Why [`Net::validate`] refuses a network: which layer or normalisation, and how.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct InvalidNet(pub String);

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
    pub fn validate(&self) -> std::result::Result<(), InvalidNet> {
        self.check_structure().map_err(InvalidNet)
    }

    fn check_structure(&self) -> std::result::Result<(), String> {
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

pub fn normalise_row(a: &Affine, raw: &[f64], dst: &mut [f32]) {
    for (((d, v), m), s) in dst.iter_mut().zip(raw).zip(&a.mean).zip(&a.std) {
        *d = ((v - m) / s) as f32;
    }
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
}
