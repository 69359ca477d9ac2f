//! How well the published answer matches at the published resolution, pooled onto the grid the confidence is
//! scored on: each published pixel's Hamming distance between the two images' 5x5 census codes at its rounded
//! disparity, summed over the published pixels of each grid cell (those the cell's confidence is upsampled
//! onto) on one of the cell's rows, then the mean over the cell's 3x3 neighbourhood of cells, in [0, 1] (1:
//! every bit differs). A feature of census-refine's confidence ([`crate::census_confidence`]), with the pooled
//! cost's curvature about the answer ([`Pooled::curv`]): the same pooling of each pixel's smaller distance one
//! pixel either side of its rounded disparity (`S1`) and two pixels either side (`S2`), `(S2 - S1) / S2`. A
//! right answer sits in a basin of the cost that is still rising two pixels away; a wrong one (a flat or
//! repetitive area, a surface the upsampling bent) has no basin there: `S2` no larger than `S1`.
//!
//! Why at the published resolution: the search runs at half of it and its answer is upsampled, so what the
//! coarse search cannot see (thin structures, a depth edge placed a pixel off, a surface the upsampling bent)
//! costs nothing there; matched again here it does (docs/depth.md). Why pooled: scored per published pixel
//! (a 7x7 box there) it ranked Aloe and Motorcycle no better, and a logistic per published pixel cost four
//! times the scoring on the grid. Census compares signs, so the two cameras' gain and offset do not enter it.
//! Why one row of each cell (the last of its rows, [`MatchCost::rows`]): the census images are then needed on
//! those rows only, half of them at the runtime's default (the network at half the published size), which
//! halves the largest part of the confidence's cost (issue 41: at most +10 % to the disparity stage). The
//! pool's 3x3 cells still hold 18 pixels there. On the development pair's halves (Aloe, fitted on one and
//! ranked on the other, docs/depth.md) the ranking was 2.23 / 0.55 % bad-2 against 2.20 / 0.55 with every
//! row, and 2.38 / 0.56 with the first row of each cell.

/// Bits of a 5x5 census code: the cost of a match outside the right image or of a pixel without an answer.
const BITS: u32 = 24;
/// The cost of two codes without a set bit: chance level. Why: a uniform patch (a saturated or black area, a
/// noiseless flat wall) has no neighbour darker than its centre in either view, so it "matches" at every
/// disparity; that is no evidence for the answer.
const NO_EVIDENCE: u32 = BITS / 2;

/// Buffers of the cost from one published size onto one grid, allocated once.
pub struct MatchCost {
    /// The published size and the grid's.
    full: (usize, usize),
    grid: (usize, usize),
    /// The published columns of each grid column: `cols[gx]..cols[gx + 1]`, the inverse of the nearest
    /// upsampling ([`crate::resample::nearest`]).
    cols: Vec<usize>,
    /// The published row each grid row is matched on: the last of those its confidence is upsampled onto (none
    /// where no published row maps to it, a grid taller than the published size).
    sel: Vec<Option<usize>>,
    /// One published row's Hamming distances, at the rounded disparity, the smaller one pixel either side of it
    /// and the smaller two pixels either side (the three channels), for each of the two halves
    /// [`MatchCost::halves`] gives.
    ham: [[Vec<u32>; 3]; 2],
    /// Per channel and grid cell, the sum of its pixels' distances, and that of the cell and its two horizontal
    /// neighbours.
    sums: [Vec<u32>; 3],
    hsums: [Vec<u32>; 3],
    /// A grid row of zeros (beyond the grid's top and bottom).
    zeros: Vec<u32>,
    /// Per grid cell, 1 / (BITS x the matched pixels of its 3x3 neighbourhood).
    inv: Vec<f32>,
    /// The pooled cost per grid cell.
    cost: Vec<f32>,
    /// The pooled cost's curvature per grid cell ([`Pooled::curv`]).
    curv: Vec<f32>,
}

/// What [`MatchCost::compute`] gives per grid cell.
#[derive(Clone, Copy)]
pub struct Pooled<'a> {
    /// The pooled cost at the answer, in [0, 1].
    pub cost: &'a [f32],
    /// `(S2 - S1) / S2` in [-1, 1] (0 where `S2` is 0): `S1`, `S2` the pooled sums of each pixel's smaller
    /// distance one and two pixels either side of its rounded disparity.
    pub curv: &'a [f32],
}

/// The first index of `0..dst` whose nearest source index (`i * src / dst`) is each of `0..=src` (the last:
/// `dst`).
fn starts(src: usize, dst: usize) -> Vec<usize> {
    let mut s = vec![dst; src + 1];
    for i in (0..dst).rev() {
        s[(i * src / dst).min(src - 1)] = i;
    }
    // a source index no destination picks (a grid larger than the published size) starts where the next does
    for k in (0..src).rev() {
        s[k] = s[k].min(s[k + 1]);
    }
    s
}

/// Both images' census codes ([`crate::census`]) the cost is computed from.
#[derive(Clone, Copy)]
pub enum Codes<'a> {
    /// Of every published row (left, right).
    Full(&'a [u32], &'a [u32]),
    /// Of the matched rows only ([`MatchCost::rows`]): row `gy` of each holds published row `rows()[gy]`'s codes.
    Rows(&'a [u32], &'a [u32]),
}

impl MatchCost {
    /// Buffers for answers of `full` (w, h) pooled onto a `grid`.
    pub fn new(full: (usize, usize), grid: (usize, usize)) -> MatchCost {
        let (cols, rows) = (starts(grid.0, full.0), starts(grid.1, full.1));
        let (gw, gh) = grid;
        let sel: Vec<Option<usize>> = (0..gh).map(|gy| (rows[gy + 1] > rows[gy]).then(|| rows[gy + 1] - 1)).collect();
        let n = |v: &[usize], i: usize| v[i + 1] - v[i];
        let mut inv = vec![0.0; gw * gh];
        for gy in 0..gh {
            let ny = (gy.saturating_sub(1)..(gy + 2).min(gh)).filter(|&k| sel[k].is_some()).count();
            for gx in 0..gw {
                let nx: usize = (gx.saturating_sub(1)..(gx + 2).min(gw)).map(|k| n(&cols, k)).sum();
                inv[gy * gw + gx] = 1.0 / (BITS as f32 * (nx * ny).max(1) as f32);
            }
        }
        MatchCost {
            full,
            grid,
            cols,
            sel,
            ham: std::array::from_fn(|_| std::array::from_fn(|_| vec![0; full.0])),
            sums: std::array::from_fn(|_| vec![0; gw * gh]),
            hsums: std::array::from_fn(|_| vec![0; gw * gh]),
            zeros: vec![0; gw],
            inv,
            cost: vec![0.0; gw * gh],
            curv: vec![0.0; gw * gh],
        }
    }

    /// The published rows the cost matches, with the grid row of each: `(gy, y)`. Only these rows' census codes
    /// are needed ([`Codes::Rows`], [`crate::census::census_rows`]).
    pub fn rows(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        self.sel.iter().enumerate().filter_map(|(gy, y)| y.map(|y| (gy, y)))
    }

    /// The cost on the grid of answer `d` (left-view disparity at the published size, NaN unknown) between
    /// the census `codes`, and its curvature. A pixel without an answer, or whose match leaves the right image,
    /// costs every bit.
    pub fn compute(&mut self, codes: Codes<'_>, d: &[f32]) -> Pooled<'_> {
        for part in self.halves(codes, d) {
            part.run();
        }
        self.finish()
    }

    /// The cost's first step (each cell's sum and the horizontal sums of three) as two parts, the grid's upper
    /// and lower rows, that two threads can run at once; [`MatchCost::finish`] then gives the cost.
    pub fn halves<'a>(&'a mut self, codes: Codes<'a>, d: &'a [f32]) -> [Pool<'a>; 2] {
        let ((w, h), (gw, gh)) = (self.full, self.grid);
        let (cl, cr, rows) = match codes {
            Codes::Full(l, r) => (l, r, h),
            Codes::Rows(l, r) => (l, r, gh),
        };
        assert!(
            cl.len() >= w * rows && cr.len() >= w * rows && d.len() >= w * h,
            "match cost: maps smaller than {w}x{h} (census codes of {rows} rows)"
        );
        let compact = matches!(codes, Codes::Rows(..));
        let mid = gh / 2;
        let split = |v: &'a mut [Vec<u32>; 3]| {
            let [a, b, c] = v.each_mut().map(|v| v.split_at_mut(mid * gw));
            ([a.0, b.0, c.0], [a.1, b.1, c.1])
        };
        let ((s0, s1), (h0, h1)) = (split(&mut self.sums), split(&mut self.hsums));
        let [a0, a1] = self.ham.each_mut().map(|h| h.each_mut().map(|v| &mut v[..]));
        let (cols, sel) = (&self.cols[..], &self.sel[..]);
        let part = |ham, sums, hsums, gy0| Pool { w, gw, cols, sel, cl, cr, compact, d, ham, sums, hsums, gy0 };
        [part(a0, s0, h0, 0), part(a1, s1, h1, mid)]
    }

    /// The cost and its curvature per grid cell once both [`MatchCost::halves`] have run: the vertical sums of
    /// three, the mean and the ratio.
    pub fn finish(&mut self) -> Pooled<'_> {
        let (gw, gh) = self.grid;
        for gy in 0..gh {
            // the vertical sum of three of channel k's horizontal sums
            let rows = |k: usize| {
                let row = |v: usize| &self.hsums[k][v * gw..(v + 1) * gw];
                let b = if gy > 0 { row(gy - 1) } else { &self.zeros[..] };
                let c = if gy + 1 < gh { row(gy + 1) } else { &self.zeros[..] };
                (row(gy), b, c)
            };
            let r = gy * gw..(gy + 1) * gw;
            let ((a0, b0, c0), (a1, b1, c1), (a2, b2, c2)) = (rows(0), rows(1), rows(2));
            let (inv, out, curv) = (&self.inv[r.clone()], &mut self.cost[r.clone()], &mut self.curv[r]);
            for x in 0..gw {
                out[x] = (a0[x] + b0[x] + c0[x]) as f32 * inv[x];
                let (s1, s2) = ((a1[x] + b1[x] + c1[x]) as f32, (a2[x] + b2[x] + c2[x]) as f32);
                curv[x] = if s2 > 0.0 { ((s2 - s1) / s2).clamp(-1.0, 1.0) } else { 0.0 };
            }
        }
        Pooled { cost: &self.cost, curv: &self.curv }
    }

    /// The last [`MatchCost::compute`]'s cost per grid cell.
    pub fn cost(&self) -> &[f32] {
        &self.cost
    }

    /// The last [`MatchCost::compute`]'s curvature per grid cell ([`Pooled::curv`]).
    pub fn curvature(&self) -> &[f32] {
        &self.curv
    }
}

/// One row's Hamming distances: left pixel x against the right pixel nearest to x - d (x - d + 1/2 truncated),
/// into `ham[0]`; the smaller of those one pixel either side of that (at x - d + 1/2 -+ 1) into `ham[1]`, two
/// pixels either side into `ham[2]`. NaN and out-of-image matches cost [`BITS`], two codes without a set bit
/// [`NO_EVIDENCE`].
#[inline(always)]
fn ham_rows(l: &[u32], r: &[u32], d: &[f32], ham: [&mut [u32]; 3]) {
    let w = l.len();
    let [h0, h1, h2] = ham;
    let mut x0 = 0;
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && [r.len(), d.len(), h0.len(), h1.len(), h2.len()] == [w; 5] {
        // SAFETY: the CPU has AVX2 (checked just above); the slices have w elements each.
        x0 = unsafe { ham_rows_avx2(l, r, d, [&mut *h0, &mut *h1, &mut *h2]) };
    }
    ham_scalar(l, r, d, [h0, h1, h2], x0)
}

/// [`ham_rows`] from column `x0` on, one pixel at a time.
#[inline(always)]
fn ham_scalar(l: &[u32], r: &[u32], d: &[f32], ham: [&mut [u32]; 3], x0: usize) {
    let w = l.len();
    let one = |x: usize, xr: f32| -> u32 {
        if xr >= 0.0 && xr < w as f32 {
            let (a, b) = (l[x], r[xr as usize]);
            if a | b == 0 {
                NO_EVIDENCE
            } else {
                (a ^ b).count_ones()
            }
        } else {
            BITS
        }
    };
    let [h0, h1, h2] = ham;
    for x in x0..w {
        let xr = x as f32 - d[x] + 0.5;
        h0[x] = one(x, xr);
        h1[x] = one(x, xr - 1.0).min(one(x, xr + 1.0));
        h2[x] = one(x, xr - 2.0).min(one(x, xr + 2.0));
    }
}

/// [`ham_rows`] eight pixels at a time (gathers of the right codes, popcounts by nibble lookup); returns the
/// first column it left to the scalar loop.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn ham_rows_avx2(l: &[u32], r: &[u32], d: &[f32], ham: [&mut [u32]; 3]) -> usize {
    use std::arch::x86_64::*;
    let w = l.len();
    let lut = _mm256_setr_epi8(
        0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4, 0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4,
    );
    let (low4, ones8, ones16) = (_mm256_set1_epi8(0x0f), _mm256_set1_epi8(1), _mm256_set1_epi16(1));
    let (half, zero, wf) = (_mm256_set1_ps(0.5), _mm256_setzero_ps(), _mm256_set1_ps(w as f32));
    let (none_cost, out_cost) = (_mm256_set1_epi32(NO_EVIDENCE as i32), _mm256_set1_epi32(BITS as i32));
    let step = _mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0);
    // the distances of the left codes `a` to the right codes at xr (the scalar loop's `one`)
    let at = |a: __m256i, xr: __m256| {
        // ordered compares: false for NaN
        let inside =
            _mm256_castps_si256(_mm256_and_ps(_mm256_cmp_ps(xr, zero, _CMP_GE_OQ), _mm256_cmp_ps(xr, wf, _CMP_LT_OQ)));
        let idx = _mm256_and_si256(_mm256_cvttps_epi32(xr), inside);
        let b = _mm256_i32gather_epi32::<4>(r.as_ptr() as *const i32, idx);
        let v = _mm256_xor_si256(a, b);
        let bytes = _mm256_add_epi8(
            _mm256_shuffle_epi8(lut, _mm256_and_si256(v, low4)),
            _mm256_shuffle_epi8(lut, _mm256_and_si256(_mm256_srli_epi16::<4>(v), low4)),
        );
        let count = _mm256_madd_epi16(_mm256_maddubs_epi16(bytes, ones8), ones16);
        let none = _mm256_cmpeq_epi32(_mm256_or_si256(a, b), _mm256_setzero_si256());
        let count = _mm256_blendv_epi8(count, none_cost, none);
        _mm256_blendv_epi8(out_cost, count, inside)
    };
    let (one, two) = (_mm256_set1_ps(1.0), _mm256_set1_ps(2.0));
    let [h0, h1, h2] = ham;
    let mut x = 0;
    while x + 8 <= w {
        let xs = _mm256_add_ps(_mm256_set1_ps(x as f32), step);
        let xr = _mm256_add_ps(_mm256_sub_ps(xs, _mm256_loadu_ps(d.as_ptr().add(x))), half);
        let a = _mm256_loadu_si256(l.as_ptr().add(x) as *const __m256i);
        let c0 = at(a, xr);
        let c1 = _mm256_min_epu32(at(a, _mm256_sub_ps(xr, one)), at(a, _mm256_add_ps(xr, one)));
        let c2 = _mm256_min_epu32(at(a, _mm256_sub_ps(xr, two)), at(a, _mm256_add_ps(xr, two)));
        _mm256_storeu_si256(h0.as_mut_ptr().add(x) as *mut __m256i, c0);
        _mm256_storeu_si256(h1.as_mut_ptr().add(x) as *mut __m256i, c1);
        _mm256_storeu_si256(h2.as_mut_ptr().add(x) as *mut __m256i, c2);
        x += 8;
    }
    x
}

/// Grid rows `gy0..` of the cost's first step ([`MatchCost::halves`]): per channel, each cell's sum of its
/// pixels' distances, and the horizontal sums of three cells.
pub struct Pool<'a> {
    w: usize,
    gw: usize,
    cols: &'a [usize],
    sel: &'a [Option<usize>],
    cl: &'a [u32],
    cr: &'a [u32],
    /// Whether the codes are of the matched rows only ([`Codes::Rows`]).
    compact: bool,
    d: &'a [f32],
    ham: [&'a mut [u32]; 3],
    /// This part's rows of the sums, per channel.
    sums: [&'a mut [u32]; 3],
    hsums: [&'a mut [u32]; 3],
    gy0: usize,
}

impl Pool<'_> {
    /// This part's rows.
    pub fn run(self) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("popcnt") {
            // SAFETY: the CPU has the instruction sets the function is compiled for (checked just above).
            unsafe { pool_avx2(self) };
            return;
        }
        pool_generic(self)
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,popcnt")]
unsafe fn pool_avx2(p: Pool<'_>) {
    pool_generic(p)
}

#[inline(always)]
fn pool_generic(p: Pool<'_>) {
    let Pool { w, gw, cols, sel, cl, cr, compact, d, mut ham, sums, hsums, gy0 } = p;
    // twice the grid's width: each cell's columns are a pair (the runtime's default), summed in one straight loop
    let pairs = w == 2 * gw;
    for k in 0..sums[0].len() / gw {
        let gy = gy0 + k;
        let cells = k * gw..(k + 1) * gw;
        let matched = if let Some(y) = sel[gy] {
            let c = if compact { gy * w } else { y * w };
            let (l, r, ds) = (&cl[c..c + w], &cr[c..c + w], &d[y * w..(y + 1) * w]);
            let [a, b, c] = &mut ham;
            ham_rows(l, r, ds, [&mut **a, &mut **b, &mut **c]);
            true
        } else {
            false
        };
        for ch in 0..3 {
            let (sums, hs) = (&mut sums[ch][cells.clone()], &mut hsums[ch][cells.clone()]);
            sums.fill(0);
            if matched {
                let ham = &ham[ch][..w];
                if pairs {
                    for (s, p) in sums.iter_mut().zip(ham.chunks_exact(2)) {
                        *s += p[0] + p[1];
                    }
                } else {
                    for (gx, s) in sums.iter_mut().enumerate() {
                        *s += ham[cols[gx]..cols[gx + 1]].iter().sum::<u32>();
                    }
                }
            }
            // the row's 3-cell horizontal sums, clipped at the grid's border; the interior as shifted slices (a
            // straight loop that vectorises: a sum per cell over its clipped range took half of this function)
            for gx in [0, gw - 1] {
                hs[gx] = sums[gx.saturating_sub(1)..(gx + 2).min(gw)].iter().sum();
            }
            if gw > 2 {
                let (a, b, c) = (&sums[..gw - 2], &sums[1..gw - 1], &sums[2..]);
                for (o, ((a, b), c)) in hs[1..gw - 1].iter_mut().zip(a.iter().zip(b).zip(c)) {
                    *o = a + b + c;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The definition, cell by cell: the nearest upsampling's pixels of each cell's 3x3 neighbourhood on each
    /// cell's last row, their Hamming distances at each rounded disparity (outside the right image or unknown:
    /// 24; two codes without a set bit: 12), summed and divided by 24 x their count; and the curvature, from the
    /// sums of each pixel's smaller distance one (`s1`) and two (`s2`) pixels either side, (s2 - s1) / s2.
    fn brute(cl: &[u32], cr: &[u32], d: &[f32], (w, h): (usize, usize), (gw, gh): (usize, usize)) -> Vec<(f32, f32)> {
        let ham = |x: usize, y: usize, k: f32| -> u32 {
            let dv = d[y * w + x];
            let xr = (x as f32 - dv + 0.5).floor() - k;
            if !dv.is_finite() || xr < 0.0 || xr as usize >= w {
                24
            } else if cl[y * w + x] == 0 && cr[y * w + xr as usize] == 0 {
                12
            } else {
                (cl[y * w + x] ^ cr[y * w + xr as usize]).count_ones()
            }
        };
        let mut out = vec![(0f32, 0f32); gw * gh];
        for gy in 0..gh {
            for gx in 0..gw {
                let (mut s, mut s1, mut s2, mut n) = (0u32, 0u32, 0u32, 0u32);
                for y in 0..h {
                    for x in 0..w {
                        let (cx, cy) = ((x * gw / w) as isize, (y * gh / h) as isize);
                        let last = y + 1 == h || ((y + 1) * gh / h) as isize != cy;
                        if last && (cx - gx as isize).abs() <= 1 && (cy - gy as isize).abs() <= 1 {
                            s += ham(x, y, 0.0);
                            s1 += ham(x, y, -1.0).min(ham(x, y, 1.0));
                            s2 += ham(x, y, -2.0).min(ham(x, y, 2.0));
                            n += 1;
                        }
                    }
                }
                let curv = if s2 > 0 { ((s2 as f32 - s1 as f32) / s2 as f32).clamp(-1.0, 1.0) } else { 0.0 };
                out[gy * gw + gx] = (s as f32 / (24 * n.max(1)) as f32, curv);
            }
        }
        out
    }

    /// Both layouts of the codes (every row, the matched rows only) at sizes that divide, that do not, at the
    /// grid's own size and onto a grid taller than the published size (rows without a match).
    #[test]
    fn pooled_cost_equals_the_definition() {
        let sizes = [((24, 12), (12, 6)), ((23, 11), (11, 5)), ((13, 7), (13, 7)), ((9, 6), (4, 4)), ((8, 5), (4, 7))];
        // curvatures of both signs were compared
        let mut signs = (false, false);
        for ((w, h), (gw, gh)) in sizes {
            let mut seed = 7u32;
            let mut next = || {
                seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                seed >> 8
            };
            let cl: Vec<u32> = (0..w * h).map(|i| if i % 5 == 0 { 0 } else { next() & 0xff_ffff }).collect();
            let cr: Vec<u32> = (0..w * h).map(|i| if i % 7 == 0 { 0 } else { next() & 0xff_ffff }).collect();
            let d: Vec<f32> =
                (0..w * h).map(|i| if i % 11 == 3 { f32::NAN } else { (next() % 80) as f32 / 8.0 - 1.0 }).collect();
            let mut mc = MatchCost::new((w, h), (gw, gh));
            let want = brute(&cl, &cr, &d, (w, h), (gw, gh));
            let got = mc.compute(Codes::Full(&cl, &cr), &d);
            let got: Vec<(f32, f32)> = got.cost.iter().copied().zip(got.curv.iter().copied()).collect();
            let (mut rl, mut rr) = (vec![u32::MAX; w * gh], vec![u32::MAX; w * gh]);
            for (gy, y) in mc.rows() {
                rl[gy * w..(gy + 1) * w].copy_from_slice(&cl[y * w..(y + 1) * w]);
                rr[gy * w..(gy + 1) * w].copy_from_slice(&cr[y * w..(y + 1) * w]);
            }
            let rows = mc.compute(Codes::Rows(&rl, &rr), &d);
            let rows: Vec<(f32, f32)> = rows.cost.iter().copied().zip(rows.curv.iter().copied()).collect();
            signs.0 |= want.iter().any(|e| e.1 > 0.0);
            signs.1 |= want.iter().any(|e| e.1 < 0.0);
            for (i, ((g, r), e)) in got.iter().zip(&rows).zip(&want).enumerate() {
                assert!((g.0 - e.0).abs() < 1e-6, "{w}x{h} onto {gw}x{gh}, cell {i}: cost {g:?} vs {e:?}");
                assert!((g.1 - e.1).abs() < 1e-6, "{w}x{h} onto {gw}x{gh}, cell {i}: curvature {g:?} vs {e:?}");
                assert_eq!(g, r, "{w}x{h} onto {gw}x{gh}, cell {i}: the matched rows' codes");
            }
        }
        assert_eq!(signs, (true, true), "curvatures of both signs");
    }

    /// The AVX2 row (where the CPU has it) gives what the scalar loop gives, NaN, negative and far disparities
    /// and uniform codes included.
    #[test]
    fn the_vector_row_is_the_scalar_row() {
        let w = 203usize;
        let mut seed = 11u32;
        let mut next = || {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            seed >> 8
        };
        let l: Vec<u32> = (0..w).map(|i| if i % 6 == 0 { 0 } else { next() & 0xff_ffff }).collect();
        let r: Vec<u32> = (0..w).map(|i| if i % 4 == 0 { 0 } else { next() & 0xff_ffff }).collect();
        let d: Vec<f32> = (0..w)
            .map(|i| match i % 9 {
                0 => f32::NAN,
                1 => -3.5,
                2 => 400.0,
                3 => i as f32 + 0.5, // exactly at the left border after rounding
                _ => (next() % 640) as f32 / 8.0,
            })
            .collect();
        let (mut fast, mut slow) =
            ([vec![0u32; w], vec![0u32; w], vec![0u32; w]], [vec![0u32; w], vec![0u32; w], vec![0u32; w]]);
        let [a, b, c] = &mut fast;
        ham_rows(&l, &r, &d, [a, b, c]);
        let [a, b, c] = &mut slow;
        ham_scalar(&l, &r, &d, [a, b, c], 0);
        assert_eq!(fast, slow);
        // every channel saw matches inside the image and outside it
        for ch in &fast {
            assert!(ch.iter().any(|&v| v < 24) && ch.contains(&24));
        }
    }

    /// The pooled cost and curvature on the grid of `img` against itself shifted left by `shift`, for each
    /// constant answer of `ds`. The census codes by their definition (crate::census makes them in the engine).
    fn at_shift(img: &[u8], (w, h): (usize, usize), shift: usize, ds: &[f32]) -> Vec<(Vec<f32>, Vec<f32>)> {
        let right: Vec<u8> = (0..w * h).map(|i| img[(i / w) * w + ((i % w) + shift).min(w - 1)]).collect();
        let census = |img: &[u8]| {
            let mut out = vec![0u32; w * h];
            for y in 0..h {
                for x in 0..w {
                    let mut bit = 0;
                    for dy in -2isize..=2 {
                        for dx in -2isize..=2 {
                            if dy == 0 && dx == 0 {
                                continue;
                            }
                            let yy = (y as isize + dy).clamp(0, h as isize - 1) as usize;
                            let xx = (x as isize + dx).clamp(0, w as isize - 1) as usize;
                            out[y * w + x] |= ((img[yy * w + xx] < img[y * w + x]) as u32) << bit;
                            bit += 1;
                        }
                    }
                }
            }
            out
        };
        let (cl, cr) = (census(img), census(&right));
        let mut mc = MatchCost::new((w, h), (w / 2, h / 2));
        ds.iter()
            .map(|&d| {
                let p = mc.compute(Codes::Full(&cl, &cr), &vec![d; w * h]);
                (p.cost.to_vec(), p.curv.to_vec())
            })
            .collect()
    }

    /// The same image both sides at its true shift costs only where the match leaves the image; a shift of one
    /// pixel off costs more everywhere the image has texture.
    #[test]
    fn the_true_shift_costs_least() {
        let (w, h) = (40usize, 20usize);
        let img: Vec<u8> = (0..w * h).map(|i| ((i * 7919 + (i / w) * 104_729) % 251) as u8).collect();
        let c = at_shift(&img, (w, h), 3, &[3.0, 4.0]);
        let i = 5 * (w / 2) + 10;
        let (right_shift, off) = (c[0].0[i], c[1].0[i]);
        assert!(right_shift < 0.05 && off > 0.2, "{right_shift} vs {off}");
    }

    /// On a texture whose neighbouring pixels are alike, as in photographs (three waves and a little noise), the
    /// true shift sits in a basin of the cost that still rises from one pixel off to two: a positive curvature.
    /// Four and five pixels off, the offsets either side are all beyond the basin: a smaller one. (The means over
    /// the grid's cells whose matches stay inside the image.)
    #[test]
    fn a_smooth_texture_has_a_basin_at_its_true_shift() {
        let (w, h) = (64usize, 24usize);
        let mut seed = 5u32;
        let img: Vec<u8> = (0..w * h)
            .map(|i| {
                seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                let v = 128.0
                    + 40.0 * (0.9 * x + 0.3 * y).sin()
                    + 30.0 * (0.5 * x - 0.7 * y + 1.0).sin()
                    + 20.0 * (1.3 * x + 0.2 * y + 2.0).sin()
                    + (seed >> 29) as f32;
                v as u8
            })
            .collect();
        let c = at_shift(&img, (w, h), 3, &[3.0, 7.0, 8.0]);
        let (gw, gh) = (w / 2, h / 2);
        let mean = |v: &[f32]| {
            let cells: Vec<f32> = (2..gh - 2).flat_map(|gy| (6..gw - 2).map(move |gx| v[gy * gw + gx])).collect();
            cells.iter().sum::<f32>() / cells.len() as f32
        };
        let (basin, far) = (mean(&c[0].1), mean(&c[1].1).max(mean(&c[2].1)));
        assert!(basin > 0.15 && far < basin / 2.0, "curvature {basin} at the true shift, {far} four pixels off");
    }
}
