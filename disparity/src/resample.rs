//! Resampling images and disparity maps between an engine's resolution and another: the one set of rules
//! every engine, the confidence and `estimate` use.
use opencv::core::{Mat, Size};
use opencv::prelude::*;

use crate::error::{cv, Result};

/// Resizes an 8-bit gray image (area averaging when shrinking, bilinear when enlarging).
pub fn resize_gray(src: &[u8], (sw, sh): (u32, u32), dst: &mut [u8], (dw, dh): (u32, u32)) -> Result<()> {
    if (sw, sh) == (dw, dh) {
        dst.copy_from_slice(src);
        return Ok(());
    }
    let s = Mat::new_rows_cols_with_data(sh as i32, sw as i32, src).map_err(cv("fused"))?;
    let mut d = Mat::default();
    let interp = if dw <= sw && dh <= sh { opencv::imgproc::INTER_AREA } else { opencv::imgproc::INTER_LINEAR };
    opencv::imgproc::resize(&s, &mut d, Size::new(dw as i32, dh as i32), 0.0, 0.0, interp).map_err(cv("fused"))?;
    dst.copy_from_slice(d.data_bytes().map_err(cv("fused"))?);
    Ok(())
}

/// Bilinear resample of a disparity map to another resolution, values scaled by the width ratio. A pixel
/// next to an invalid one takes its nearest neighbour instead, so invalid (NaN) never spreads nor blends.
pub fn upsample_disparity(src: &[f32], (sw, sh): (usize, usize), dst: &mut [f32], (dw, dh): (usize, usize)) {
    let scale = dw as f32 / sw as f32;
    let (fx, fy) = (sw as f32 / dw as f32, sh as f32 / dh as f32);
    // the coordinates are clamped to >= 0, so a cast is the floor: no libm call per pixel (the baseline
    // x86-64 target has no rounding instruction), which made this a tenth of the refinement's frame
    for (y, row) in dst.chunks_exact_mut(dw).enumerate().take(dh) {
        let syf = ((y as f32 + 0.5) * fy - 0.5).clamp(0.0, (sh - 1) as f32);
        let y0 = syf as usize;
        let ty = syf - y0 as f32;
        let y1 = (y0 + 1).min(sh - 1);
        let (r0, r1) = (&src[y0 * sw..(y0 + 1) * sw], &src[y1 * sw..(y1 + 1) * sw]);
        let yn = if ty < 0.5 { r0 } else { r1 };
        if dw == 2 * sw && sw >= 2 {
            twice_row(r0, r1, yn, ty, scale, row);
            continue;
        }
        for (x, o) in row.iter_mut().enumerate() {
            let sxf = ((x as f32 + 0.5) * fx - 0.5).clamp(0.0, (sw - 1) as f32);
            let x0 = sxf as usize;
            let tx = sxf - x0 as f32;
            let x1 = (x0 + 1).min(sw - 1);
            let (a, b, c, d) = (r0[x0], r0[x1], r1[x0], r1[x1]);
            let v = if a.is_finite() && b.is_finite() && c.is_finite() && d.is_finite() {
                (a * (1.0 - tx) + b * tx) * (1.0 - ty) + (c * (1.0 - tx) + d * tx) * ty
            } else {
                yn[if tx < 0.5 { x0 } else { x1 }]
            };
            *o = v * scale;
        }
    }
}

/// One bilinear tap of [`upsample_disparity`]: the blend of the four neighbours when all are finite, else
/// the nearest (`n`). Both are computed and one selected, so that a row of them vectorises.
#[inline(always)]
fn tap([a, b, c, d]: [f32; 4], n: f32, tx: f32, ty: f32, scale: f32) -> f32 {
    let blend = (a * (1.0 - tx) + b * tx) * (1.0 - ty) + (c * (1.0 - tx) + d * tx) * ty;
    let all = a.is_finite() & b.is_finite() & c.is_finite() & d.is_finite();
    (if all { blend } else { n }) * scale
}

/// A row of [`upsample_disparity`] at exactly twice the width (the runtime's default, 320 -> 640): output
/// 2k + 1 and 2k + 2 sit a quarter and three quarters between source k and k + 1 (tx 0.25 and 0.75, exact in
/// f32), so the same arithmetic as the general loop, bit for bit, without its per-pixel coordinates and
/// branches (the general loop took 3.5 ms of every default frame; this one vectorises).
fn twice_row(r0: &[f32], r1: &[f32], yn: &[f32], ty: f32, scale: f32, row: &mut [f32]) {
    let sw = r0.len();
    // the ends: the coordinate clamps to the first and the last source pixel (tx 0)
    row[0] = tap([r0[0], r0[1], r1[0], r1[1]], yn[0], 0.0, ty, scale);
    row[2 * sw - 1] = tap([r0[sw - 1], r0[sw - 1], r1[sw - 1], r1[sw - 1]], yn[sw - 1], 0.0, ty, scale);
    let pairs = row[1..2 * sw - 1].chunks_exact_mut(2);
    for (k, o) in pairs.enumerate() {
        let q = [r0[k], r0[k + 1], r1[k], r1[k + 1]];
        o[0] = tap(q, yn[k], 0.25, ty, scale);
        o[1] = tap(q, yn[k + 1], 0.75, ty, scale);
    }
}

/// Nearest-neighbour resample of a `(sw, sh)` map into `(dw, dh)`.
pub fn nearest<T: Copy>(src: &[T], (sw, sh): (usize, usize), dst: &mut [T], (dw, dh): (usize, usize)) {
    // no division per pixel (it cost more than the confidence's scoring, issue 41): x sw / dw stepped by
    // its quotient and remainder, and a row that repeats the source row above is a copy of the one above
    let mut prev_sy = usize::MAX;
    for y in 0..dh.min(dst.len() / dw.max(1)) {
        let sy = (y * sh / dh).min(sh - 1);
        let (done, rest) = dst.split_at_mut(y * dw);
        let row = &mut rest[..dw];
        if sy == prev_sy {
            row.copy_from_slice(&done[(y - 1) * dw..]);
            continue;
        }
        prev_sy = sy;
        let s = &src[sy * sw..(sy + 1) * sw];
        if dw == 2 * sw {
            // twice the width (the runtime's default): each value twice, in a loop that vectorises
            for (o, &v) in row.chunks_exact_mut(2).zip(s) {
                o[0] = v;
                o[1] = v;
            }
            continue;
        }
        let (mut q, mut r) = (0usize, 0usize);
        for o in row.iter_mut() {
            *o = s[q.min(sw - 1)];
            r += sw;
            while r >= dw {
                r -= dw;
                q += 1;
            }
        }
    }
}

/// Nearest-neighbour resample of a `(mw, mh)` map to `(iw, ih)`, sampling at pixel centres (the left-right
/// check's confidence and reasons of a network that ran at another resolution than its input's).
pub fn nearest_centred<T: Copy>(m: &[T], (mw, mh): (usize, usize), out: &mut [T], (iw, ih): (usize, usize)) {
    for y in 0..ih {
        let yy = (((y as f32 + 0.5) * mh as f32 / ih as f32) as usize).min(mh - 1);
        for x in 0..iw {
            let xx = (((x as f32 + 0.5) * mw as f32 / iw as f32) as usize).min(mw - 1);
            out[y * iw + x] = m[yy * mw + xx];
        }
    }
}

/// An 8-bit gray image resized to `w` x `h` (INTER_AREA; a copy when it has that size already).
pub fn resize_mat(m: &Mat, w: i32, h: i32) -> Result<Vec<u8>> {
    let cv = cv("resize");
    let mut r = Mat::default();
    if m.cols() == w && m.rows() == h {
        r = m.try_clone().map_err(&cv)?;
    } else {
        opencv::imgproc::resize(m, &mut r, Size::new(w, h), 0.0, 0.0, opencv::imgproc::INTER_AREA).map_err(&cv)?;
    }
    Ok(r.data_bytes().map_err(&cv)?.to_vec())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The stepped `nearest` picks what x sw / dw, y sh / dh pick, up and down, integer factor or not.
    #[test]
    fn nearest_picks_the_divided_index() {
        for (sw, sh, dw, dh) in [(320, 240, 640, 480), (7, 5, 16, 11), (16, 11, 7, 5), (3, 3, 3, 3), (5, 2, 13, 9)] {
            let src: Vec<u32> = (0..sw * sh).map(|i| i as u32).collect();
            let mut dst = vec![0u32; dw * dh];
            nearest(&src, (sw, sh), &mut dst, (dw, dh));
            for y in 0..dh {
                for x in 0..dw {
                    let want = (y * sh / dh).min(sh - 1) * sw + (x * sw / dw).min(sw - 1);
                    assert_eq!(dst[y * dw + x], want as u32, "{sw}x{sh} -> {dw}x{dh} at ({x}, {y})");
                }
            }
        }
    }

    /// The general loop of [`upsample_disparity`], kept as the definition the twice-the-width row is checked
    /// against.
    fn upsample_general(src: &[f32], (sw, sh): (usize, usize), dst: &mut [f32], (dw, dh): (usize, usize)) {
        let scale = dw as f32 / sw as f32;
        let (fx, fy) = (sw as f32 / dw as f32, sh as f32 / dh as f32);
        for (y, row) in dst.chunks_exact_mut(dw).enumerate().take(dh) {
            let syf = ((y as f32 + 0.5) * fy - 0.5).clamp(0.0, (sh - 1) as f32);
            let (y0, ty) = (syf as usize, syf - (syf as usize) as f32);
            let y1 = (y0 + 1).min(sh - 1);
            let (r0, r1) = (&src[y0 * sw..(y0 + 1) * sw], &src[y1 * sw..(y1 + 1) * sw]);
            let yn = if ty < 0.5 { r0 } else { r1 };
            for (x, o) in row.iter_mut().enumerate() {
                let sxf = ((x as f32 + 0.5) * fx - 0.5).clamp(0.0, (sw - 1) as f32);
                let (x0, tx) = (sxf as usize, sxf - (sxf as usize) as f32);
                let x1 = (x0 + 1).min(sw - 1);
                let (a, b, c, d) = (r0[x0], r0[x1], r1[x0], r1[x1]);
                let v = if a.is_finite() && b.is_finite() && c.is_finite() && d.is_finite() {
                    (a * (1.0 - tx) + b * tx) * (1.0 - ty) + (c * (1.0 - tx) + d * tx) * ty
                } else {
                    yn[if tx < 0.5 { x0 } else { x1 }]
                };
                *o = v * scale;
            }
        }
    }

    /// At twice the width the row fast path gives the general loop's output bit for bit: random values with
    /// NaN, infinities and negative zeros, at several sizes (the ends included).
    #[test]
    fn twice_the_width_is_the_general_loop_bit_for_bit() {
        let mut s = 0x2545f491u32;
        let mut next = || {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            s
        };
        for (sw, sh, dh) in [(320, 240, 480), (2, 2, 4), (3, 5, 10), (17, 4, 7), (64, 3, 6)] {
            let src: Vec<f32> = (0..sw * sh)
                .map(|_| match next() % 16 {
                    0 => f32::NAN,
                    1 => f32::INFINITY,
                    2 => -0.0,
                    _ => (next() % 100_000) as f32 / 997.0,
                })
                .collect();
            let (mut fast, mut want) = (vec![0f32; 2 * sw * dh], vec![0f32; 2 * sw * dh]);
            upsample_disparity(&src, (sw, sh), &mut fast, (2 * sw, dh));
            upsample_general(&src, (sw, sh), &mut want, (2 * sw, dh));
            for (i, (a, b)) in fast.iter().zip(&want).enumerate() {
                assert_eq!(a.to_bits(), b.to_bits(), "{sw}x{sh} -> {}x{dh} at {i}: {a} vs {b}", 2 * sw);
            }
        }
    }

    #[test]
    fn upsampling_scales_values_and_never_blends_invalid() {
        // a 4x2 ramp to 8x4: values double, a constant stays constant (times 2)
        let src = [1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0];
        let mut dst = [0f32; 32];
        upsample_disparity(&src, (4, 2), &mut dst, (8, 4));
        assert!(dst.iter().all(|v| (*v - 2.0).abs() < 1e-6), "{dst:?}");
        // one invalid source pixel: the output is NaN only where it is the nearest, never a blend
        let mut src = [4.0f32; 8];
        src[0] = f32::NAN;
        upsample_disparity(&src, (4, 2), &mut dst, (8, 4));
        for v in dst {
            assert!(v.is_nan() || (v - 8.0).abs() < 1e-6, "{v}");
        }
        assert!(dst[0].is_nan() && dst[1].is_nan());
        assert_eq!(dst.iter().filter(|v| v.is_nan()).count(), 4);
    }
}
