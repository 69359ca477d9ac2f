//! How well the published answer matches at the published resolution, pooled onto the grid the confidence is
//! scored on: each published pixel's Hamming distance between the two images' 5x5 census codes at its rounded
//! disparity, summed over the published pixels of each grid cell (those the cell's confidence is upsampled
//! onto) on one of the cell's rows, then the mean over the cell's 3x3 neighbourhood of cells, in [0, 1] (1:
//! every bit differs). A feature of census-refine's confidence ([`crate::census_confidence`]).
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
    /// One published row's Hamming distances, for each of the two halves [`MatchCost::halves`] gives.
    ham: [Vec<u32>; 2],
    /// Per grid cell, the sum of its pixels' distances, and that of the cell and its two horizontal neighbours.
    sums: Vec<u32>,
    hsums: Vec<u32>,
    /// A grid row of zeros (beyond the grid's top and bottom).
    zeros: Vec<u32>,
    /// Per grid cell, 1 / (BITS x the matched pixels of its 3x3 neighbourhood).
    inv: Vec<f32>,
    /// The pooled cost per grid cell.
    cost: Vec<f32>,
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
            ham: [vec![0; full.0], vec![0; full.0]],
            sums: vec![0; gw * gh],
            hsums: vec![0; gw * gh],
            zeros: vec![0; gw],
            inv,
            cost: vec![0.0; gw * gh],
        }
    }

    /// The published rows the cost matches, with the grid row of each: `(gy, y)`. Only these rows' census codes
    /// are needed ([`Codes::Rows`], [`crate::census::census_rows`]).
    pub fn rows(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        self.sel.iter().enumerate().filter_map(|(gy, y)| y.map(|y| (gy, y)))
    }

    /// The cost on the grid of answer `d` (left-view disparity at the published size, NaN unknown) between
    /// the census `codes`. A pixel without an answer, or whose match leaves the right image, costs every bit.
    pub fn compute(&mut self, codes: Codes<'_>, d: &[f32]) -> &[f32] {
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
        let (s0, s1) = self.sums.split_at_mut(mid * gw);
        let (h0, h1) = self.hsums.split_at_mut(mid * gw);
        let [a0, a1] = &mut self.ham;
        let (cols, sel) = (&self.cols[..], &self.sel[..]);
        let part = |ham, sums, hsums, gy0| Pool { w, gw, cols, sel, cl, cr, compact, d, ham, sums, hsums, gy0 };
        [part(&mut a0[..], s0, h0, 0), part(&mut a1[..], s1, h1, mid)]
    }

    /// The cost per grid cell once both [`MatchCost::halves`] have run: the vertical sums of three and the mean.
    pub fn finish(&mut self) -> &[f32] {
        let (gw, gh) = self.grid;
        for gy in 0..gh {
            let row = |v: usize| &self.hsums[v * gw..(v + 1) * gw];
            let a = row(gy);
            let b = if gy > 0 { row(gy - 1) } else { &self.zeros[..] };
            let c = if gy + 1 < gh { row(gy + 1) } else { &self.zeros[..] };
            let (inv, out) = (&self.inv[gy * gw..(gy + 1) * gw], &mut self.cost[gy * gw..(gy + 1) * gw]);
            for x in 0..gw {
                out[x] = (a[x] + b[x] + c[x]) as f32 * inv[x];
            }
        }
        &self.cost
    }

    /// The last [`MatchCost::compute`]'s cost per grid cell.
    pub fn cost(&self) -> &[f32] {
        &self.cost
    }
}

/// One row's Hamming distances: left pixel x against the right pixel nearest to x - d (x - d + 1/2 truncated);
/// NaN and out-of-image matches cost [`BITS`], two codes without a set bit [`NO_EVIDENCE`].
#[inline(always)]
fn ham_row(l: &[u32], r: &[u32], d: &[f32], ham: &mut [u32]) {
    let w = l.len();
    let mut x0 = 0;
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && r.len() == w && d.len() == w && ham.len() == w {
        // SAFETY: the CPU has AVX2 (checked just above); the slices have w elements each.
        x0 = unsafe { ham_row_avx2(l, r, d, ham) };
    }
    ham_scalar(l, r, d, ham, x0)
}

/// [`ham_row`] from column `x0` on, one pixel at a time.
#[inline(always)]
fn ham_scalar(l: &[u32], r: &[u32], d: &[f32], ham: &mut [u32], x0: usize) {
    let w = l.len();
    for x in x0..w {
        let xr = x as f32 - d[x] + 0.5;
        ham[x] = if xr >= 0.0 && xr < w as f32 {
            let (a, b) = (l[x], r[xr as usize]);
            if a | b == 0 {
                NO_EVIDENCE
            } else {
                (a ^ b).count_ones()
            }
        } else {
            BITS
        };
    }
}

/// [`ham_row`] eight pixels at a time (a gather of the right codes, popcounts by nibble lookup); returns the
/// first column it left to the scalar loop.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn ham_row_avx2(l: &[u32], r: &[u32], d: &[f32], ham: &mut [u32]) -> usize {
    use std::arch::x86_64::*;
    let w = l.len();
    let lut = _mm256_setr_epi8(
        0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4, 0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4,
    );
    let (low4, ones8, ones16) = (_mm256_set1_epi8(0x0f), _mm256_set1_epi8(1), _mm256_set1_epi16(1));
    let (half, zero, wf) = (_mm256_set1_ps(0.5), _mm256_setzero_ps(), _mm256_set1_ps(w as f32));
    let (none_cost, out_cost) = (_mm256_set1_epi32(NO_EVIDENCE as i32), _mm256_set1_epi32(BITS as i32));
    let step = _mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0);
    let mut x = 0;
    while x + 8 <= w {
        let xs = _mm256_add_ps(_mm256_set1_ps(x as f32), step);
        let xr = _mm256_add_ps(_mm256_sub_ps(xs, _mm256_loadu_ps(d.as_ptr().add(x))), half);
        // ordered compares: false for NaN
        let inside =
            _mm256_castps_si256(_mm256_and_ps(_mm256_cmp_ps(xr, zero, _CMP_GE_OQ), _mm256_cmp_ps(xr, wf, _CMP_LT_OQ)));
        let idx = _mm256_and_si256(_mm256_cvttps_epi32(xr), inside);
        let b = _mm256_i32gather_epi32::<4>(r.as_ptr() as *const i32, idx);
        let a = _mm256_loadu_si256(l.as_ptr().add(x) as *const __m256i);
        let v = _mm256_xor_si256(a, b);
        let bytes = _mm256_add_epi8(
            _mm256_shuffle_epi8(lut, _mm256_and_si256(v, low4)),
            _mm256_shuffle_epi8(lut, _mm256_and_si256(_mm256_srli_epi16::<4>(v), low4)),
        );
        let count = _mm256_madd_epi16(_mm256_maddubs_epi16(bytes, ones8), ones16);
        let none = _mm256_cmpeq_epi32(_mm256_or_si256(a, b), _mm256_setzero_si256());
        let count = _mm256_blendv_epi8(count, none_cost, none);
        let count = _mm256_blendv_epi8(out_cost, count, inside);
        _mm256_storeu_si256(ham.as_mut_ptr().add(x) as *mut __m256i, count);
        x += 8;
    }
    x
}

/// Grid rows `gy0..` of the cost's first step ([`MatchCost::halves`]): each cell's sum of its pixels' distances,
/// and the horizontal sums of three cells.
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
    ham: &'a mut [u32],
    /// This part's rows of the sums.
    sums: &'a mut [u32],
    hsums: &'a mut [u32],
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
    let Pool { w, gw, cols, sel, cl, cr, compact, d, ham, sums, hsums, gy0 } = p;
    // twice the grid's width: each cell's columns are a pair (the runtime's default), summed in one straight loop
    let pairs = w == 2 * gw;
    for (k, (sums, hs)) in sums.chunks_exact_mut(gw).zip(hsums.chunks_exact_mut(gw)).enumerate() {
        let gy = gy0 + k;
        sums.fill(0);
        if let Some(y) = sel[gy] {
            let c = if compact { gy * w } else { y * w };
            let (l, r, ds) = (&cl[c..c + w], &cr[c..c + w], &d[y * w..(y + 1) * w]);
            ham_row(l, r, ds, ham);
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The definition, cell by cell: the nearest upsampling's pixels of each cell's 3x3 neighbourhood on each
    /// cell's last row, their Hamming distances at each rounded disparity (outside the right image or unknown:
    /// 24; two codes without a set bit: 12), summed and divided by 24 x their count.
    fn brute(cl: &[u32], cr: &[u32], d: &[f32], (w, h): (usize, usize), (gw, gh): (usize, usize)) -> Vec<f32> {
        let ham = |x: usize, y: usize| -> u32 {
            let dv = d[y * w + x];
            let xr = (x as f32 - dv + 0.5).floor();
            if !dv.is_finite() || xr < 0.0 || xr as usize >= w {
                24
            } else if cl[y * w + x] == 0 && cr[y * w + xr as usize] == 0 {
                12
            } else {
                (cl[y * w + x] ^ cr[y * w + xr as usize]).count_ones()
            }
        };
        let mut out = vec![0f32; gw * gh];
        for gy in 0..gh {
            for gx in 0..gw {
                let (mut s, mut n) = (0u32, 0u32);
                for y in 0..h {
                    for x in 0..w {
                        let (cx, cy) = ((x * gw / w) as isize, (y * gh / h) as isize);
                        let last = y + 1 == h || ((y + 1) * gh / h) as isize != cy;
                        if last && (cx - gx as isize).abs() <= 1 && (cy - gy as isize).abs() <= 1 {
                            s += ham(x, y);
                            n += 1;
                        }
                    }
                }
                out[gy * gw + gx] = s as f32 / (24 * n.max(1)) as f32;
            }
        }
        out
    }

    /// Both layouts of the codes (every row, the matched rows only) at sizes that divide, that do not, at the
    /// grid's own size and onto a grid taller than the published size (rows without a match).
    #[test]
    fn pooled_cost_equals_the_definition() {
        let sizes = [((24, 12), (12, 6)), ((23, 11), (11, 5)), ((13, 7), (13, 7)), ((9, 6), (4, 4)), ((8, 5), (4, 7))];
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
            let got = mc.compute(Codes::Full(&cl, &cr), &d).to_vec();
            let (mut rl, mut rr) = (vec![u32::MAX; w * gh], vec![u32::MAX; w * gh]);
            for (gy, y) in mc.rows() {
                rl[gy * w..(gy + 1) * w].copy_from_slice(&cl[y * w..(y + 1) * w]);
                rr[gy * w..(gy + 1) * w].copy_from_slice(&cr[y * w..(y + 1) * w]);
            }
            let rows = mc.compute(Codes::Rows(&rl, &rr), &d).to_vec();
            for (i, ((g, r), e)) in got.iter().zip(&rows).zip(&want).enumerate() {
                assert!((g - e).abs() < 1e-6, "{w}x{h} onto {gw}x{gh}, cell {i}: {g} vs {e}");
                assert_eq!(g, r, "{w}x{h} onto {gw}x{gh}, cell {i}: the matched rows' codes");
            }
        }
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
        let (mut fast, mut slow) = (vec![0u32; w], vec![0u32; w]);
        ham_row(&l, &r, &d, &mut fast);
        ham_scalar(&l, &r, &d, &mut slow, 0);
        assert_eq!(fast, slow);
    }

    /// The same image both sides at its true shift costs only where the match leaves the image; a shift of one
    /// pixel off costs more everywhere the image has texture.
    #[test]
    fn the_true_shift_costs_least() {
        let (w, h) = (40usize, 20usize);
        let img: Vec<u8> = (0..w * h).map(|i| ((i * 7919 + (i / w) * 104_729) % 251) as u8).collect();
        let shift = 3usize;
        let right: Vec<u8> = (0..w * h).map(|i| img[(i / w) * w + ((i % w) + shift).min(w - 1)]).collect();
        let (mut cl, mut cr) = (vec![0u32; w * h], vec![0u32; w * h]);
        // the census codes by their definition (crate::census computes them in the engine)
        let census = |img: &[u8], out: &mut [u32]| {
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
        };
        census(&img, &mut cl);
        census(&right, &mut cr);
        let mut mc = MatchCost::new((w, h), (w / 2, h / 2));
        let at = |mc: &mut MatchCost, d: f32| mc.compute(Codes::Full(&cl, &cr), &vec![d; w * h])[5 * (w / 2) + 10];
        let (right_shift, off) = (at(&mut mc, shift as f32), at(&mut mc, shift as f32 + 1.0));
        assert!(right_shift < 0.05 && off > 0.2, "{right_shift} vs {off}");
    }
}
