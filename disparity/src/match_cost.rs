//! How well the published answer matches at the published resolution: the mean Hamming distance of the two
//! images' 5x5 census codes at each pixel's rounded disparity, over a 7x7 box (the search's window), in [0, 1]
//! (1: every bit differs; two codes without a set bit, a uniform patch, count as chance). A feature of census-refine's confidence ([`crate::census_confidence`]).
//!
//! Why at the published resolution: the search runs at half of it and its answer is upsampled, so what the
//! coarse search cannot see (thin structures, a depth edge placed a pixel off, a surface the upsampling bent)
//! costs nothing there; matched again here it does. On Aloe's held-back halves it took bad-2 among the
//! 72.5 % most confident from 3.01 / 0.90 % to 2.14 / 0.44 % (docs/depth.md). Census compares signs, so the
//! two cameras' gain and offset do not enter it (the sum of absolute differences ranked a little better on
//! Aloe, whose two views were exposed alike, and was left out for that reason).

/// Bits of a 5x5 census code: the cost of a match outside the right image.
const BITS: u8 = 24;
/// The cost of two codes without a set bit: chance level. Why: a uniform patch (a saturated or black area, a
/// noiseless flat wall) has no neighbour darker than its centre in either view, so it "matches" at every
/// disparity; that is no evidence for the answer.
const NO_EVIDENCE: u8 = BITS / 2;
/// Radius of the aggregation box (7x7, the census search's window).
const R: usize = 3;

/// Buffers of the cost at one resolution, allocated once (nothing per frame).
pub struct MatchCost {
    w: usize,
    h: usize,
    /// Each pixel's Hamming distance at its rounded disparity.
    ham: Vec<u8>,
    /// Column sums of `ham` over the box's rows.
    col: Vec<u16>,
    /// 1 / the box's columns inside the image, per column.
    inv_cols: Vec<f32>,
    /// The box mean, in [0, 1].
    cost: Vec<f32>,
}

impl MatchCost {
    /// Buffers for `w` x `h` maps.
    pub fn new(w: usize, h: usize) -> MatchCost {
        let inv_cols = (0..w).map(|x| 1.0 / (x.min(R) + 1 + (w - 1 - x).min(R)) as f32).collect();
        MatchCost { w, h, ham: vec![0; w * h], col: vec![0; w], inv_cols, cost: vec![0.0; w * h] }
    }

    /// The last [`MatchCost::compute`]'s cost per pixel.
    pub fn cost(&self) -> &[f32] {
        &self.cost
    }

    /// The cost of answer `d` (left-view disparity, NaN unknown) between census codes `cl` and `cr` (this
    /// size). A pixel without an answer, or whose match leaves the right image, costs every bit; the box is
    /// clipped at the image's border (the mean of the pixels inside it).
    pub fn compute(&mut self, cl: &[u32], cr: &[u32], d: &[f32]) -> &[f32] {
        let (w, h) = (self.w, self.h);
        for (y, (ham, ds)) in self.ham.chunks_exact_mut(w).zip(d.chunks_exact(w)).take(h).enumerate() {
            let (l, r) = (&cl[y * w..(y + 1) * w], &cr[y * w..(y + 1) * w]);
            for (x, (o, &dv)) in ham.iter_mut().zip(ds).enumerate() {
                // rounded half up; NaN and negative disparities fall outside (the cast saturates NaN to 0)
                let xr = x as f32 - dv + 0.5;
                *o = if dv.is_finite() && xr >= 0.0 && (xr as usize) < w {
                    let (a, b) = (l[x], r[xr as usize]);
                    if a | b == 0 {
                        NO_EVIDENCE
                    } else {
                        (a ^ b).count_ones() as u8
                    }
                } else {
                    BITS
                };
            }
        }
        // the box: column sums over rows y - R ..= y + R kept running down the image, then a running row sum
        self.col.fill(0);
        for row in self.ham.chunks_exact(w).take(R.min(h)) {
            self.col.iter_mut().zip(row).for_each(|(c, &v)| *c += v as u16);
        }
        for y in 0..h {
            if y + R < h {
                let row = &self.ham[(y + R) * w..(y + R + 1) * w];
                self.col.iter_mut().zip(row).for_each(|(c, &v)| *c += v as u16);
            }
            let rows = (y.min(R) + 1 + (h - 1 - y).min(R)) as f32;
            let scale = 1.0 / (rows * BITS as f32);
            let out = &mut self.cost[y * w..(y + 1) * w];
            let mut s: u32 = self.col[..R.min(w)].iter().map(|&c| c as u32).sum();
            for x in 0..w {
                if x + R < w {
                    s += self.col[x + R] as u32;
                }
                out[x] = s as f32 * self.inv_cols[x] * scale;
                if x >= R {
                    s -= self.col[x - R] as u32;
                }
            }
            if y >= R {
                let row = &self.ham[(y - R) * w..(y - R + 1) * w];
                self.col.iter_mut().zip(row).for_each(|(c, &v)| *c -= v as u16);
            }
        }
        &self.cost
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The definition, pixel by pixel: the clipped box's mean of the Hamming distances at each rounded
    /// disparity (outside the right image or unknown: 24).
    fn brute(cl: &[u32], cr: &[u32], d: &[f32], w: usize, h: usize) -> Vec<f32> {
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
        let mut out = vec![0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let (mut s, mut n) = (0u32, 0u32);
                for yy in y.saturating_sub(R)..=(y + R).min(h - 1) {
                    for xx in x.saturating_sub(R)..=(x + R).min(w - 1) {
                        s += ham(xx, yy);
                        n += 1;
                    }
                }
                out[y * w + x] = s as f32 / (n * 24) as f32;
            }
        }
        out
    }

    #[test]
    fn running_box_equals_the_definition() {
        let (w, h) = (23usize, 11usize);
        let mut seed = 7u32;
        let mut next = || {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            seed
        };
        // some codes without a set bit (uniform patches)
        let cl: Vec<u32> = (0..w * h).map(|_| next() & 0xFF_FFFF).map(|c| if c % 5 == 0 { 0 } else { c }).collect();
        let cr: Vec<u32> = (0..w * h).map(|_| next() & 0xFF_FFFF).map(|c| if c % 3 == 0 { 0 } else { c }).collect();
        let d: Vec<f32> = (0..w * h)
            .map(|_| match next() % 9 {
                0 => f32::NAN,
                1 => -1.0,
                2 => 30.0,
                _ => (next() % 800) as f32 / 100.0,
            })
            .collect();
        let got = MatchCost::new(w, h).compute(&cl, &cr, &d).to_vec();
        let want = brute(&cl, &cr, &d, w, h);
        for (i, (g, e)) in got.iter().zip(&want).enumerate() {
            assert!((g - e).abs() < 1e-6, "pixel {i}: {g} vs {e}");
        }
    }

    #[test]
    fn the_true_shift_costs_nothing_and_a_wrong_one_costs() {
        let (w, h) = (40usize, 12usize);
        let cl: Vec<u32> = (0..w * h).map(|i| ((i as u32).wrapping_mul(2_654_435_761)) >> 8).collect();
        // the right view: the left shifted by 4 px
        let cr: Vec<u32> = (0..w * h).map(|i| if i % w + 4 < w { cl[i + 4] } else { 0 }).collect();
        let mut m = MatchCost::new(w, h);
        let right = m.compute(&cl, &cr, &vec![4.0; w * h]).to_vec();
        let wrong = m.compute(&cl, &cr, &vec![6.0; w * h]).to_vec();
        let i = 6 * w + 20;
        assert_eq!(right[i], 0.0);
        assert!(wrong[i] > 0.3, "{}", wrong[i]);
        // a uniform patch matches at every disparity: chance, whatever the answer
        let flat = vec![0u32; w * h];
        assert_eq!(m.compute(&flat, &flat, &vec![4.0; w * h])[i], 0.5);
    }
}
