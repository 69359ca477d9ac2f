//! Minimal PNG heatmaps (no fonts: the numbers go in the accompanying CSV/report).
use anyhow::Context;
use image::{Rgb, RgbImage};
use std::path::Path;

/// Viridis-like colour for t in [0, 1] (5-point piecewise-linear approximation).
pub fn colour(t: f64) -> Rgb<u8> {
    const STOPS: [[f64; 3]; 5] =
        [[68.0, 1.0, 84.0], [59.0, 82.0, 139.0], [33.0, 145.0, 140.0], [94.0, 201.0, 98.0], [253.0, 231.0, 37.0]];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        return Rgb([255, 255, 255]);
    };
    let x = t * 4.0;
    let i = (x.floor() as usize).min(3);
    let f = x - i as f64;
    let c = |k: usize| (STOPS[i][k] * (1.0 - f) + STOPS[i + 1][k] * f).round() as u8;
    Rgb([c(0), c(1), c(2)])
}

/// Heatmap of (row, col, value) points on a regular grid of `step`, taking the max of values
/// that share a cell; rows top to bottom = increasing row coordinate. A colour bar (low at the
/// bottom) is drawn on the right. Empty cells are white.
pub fn heatmap_max(points: &[(f64, f64, f64)], step: f64, path: &Path, _title: &str) -> anyhow::Result<()> {
    anyhow::ensure!(!points.is_empty(), "nothing to plot for {}", path.display());
    let (mut r0, mut r1, mut c0, mut c1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    let (mut lo, mut hi) = (f64::MAX, f64::MIN);
    for &(r, c, v) in points {
        r0 = r0.min(r);
        r1 = r1.max(r);
        c0 = c0.min(c);
        c1 = c1.max(c);
        lo = lo.min(v);
        hi = hi.max(v);
    }
    let nr = ((r1 - r0) / step).round() as usize + 1;
    let nc = ((c1 - c0) / step).round() as usize + 1;
    let mut cells = vec![f64::NAN; nr * nc];
    for &(r, c, v) in points {
        let i = ((r - r0) / step).round() as usize;
        let j = ((c - c0) / step).round() as usize;
        let cell = &mut cells[i * nc + j];
        if cell.is_nan() || v > *cell {
            *cell = v;
        }
    }
    let px = (480 / nr.max(nc)).max(4) as u32;
    let (w, h) = (nc as u32 * px + 40, nr as u32 * px);
    let mut img = RgbImage::from_pixel(w, h, Rgb([255, 255, 255]));
    let span = if hi > lo { hi - lo } else { 1.0 };
    for i in 0..nr {
        for j in 0..nc {
            let v = cells[i * nc + j];
            let col = if v.is_nan() { Rgb([255, 255, 255]) } else { colour((v - lo) / span) };
            for y in 0..px {
                for x in 0..px {
                    img.put_pixel(j as u32 * px + x, i as u32 * px + y, col);
                }
            }
        }
    }
    for y in 0..h {
        let col = colour(1.0 - y as f64 / (h.max(2) - 1) as f64);
        for x in (w - 25)..(w - 5) {
            img.put_pixel(x, y, col);
        }
    }
    img.save(path).with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}
