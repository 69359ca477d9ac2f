//! The fused engine: OpenCV SGBM where its own checks accept a match, the network everywhere else.
//!
//! Why: on real photographs the matches SGBM accepts (uniqueness ratio, left-right agreement within 1 px,
//! speckle filter) are right to a fraction of a pixel, but it leaves 15-30 % of the pixels without an answer
//! (occlusions, textureless areas, the band at the left edge it cannot search). The network answers
//! everywhere but coarsely (slanted planes on 8x8 px tiles, trained on rendered scenes only). The fusion keeps
//! SGBM's precision where it has it and the network's density elsewhere. SGBM runs at the engine's
//! resolution (the input's, offline), the network at its own; SGBM's search range comes from the network's
//! answer, so no range has to be configured and the band SGBM leaves at the left edge is no wider than the
//! scene needs.
use opencv::core::{Mat, Size};
use opencv::prelude::*;

use super::disparity::{DisparityEngine, OnnxEngine, SgbmEngine};
use abvs_runtime_core::error::{Result, RuntimeError};

/// Where a fused pixel's disparity came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Source {
    /// SGBM's match, accepted by its uniqueness, left-right and speckle checks.
    Sgbm = 0,
    /// The network's answer (SGBM had none).
    Network = 1,
    /// Neither engine answered.
    None = 2,
}

/// SGBM's range from the network's answer: 1.2x its 99.5th percentile plus 8 px, in steps of 16.
const RANGE_QUANTILE: f64 = 0.995;

/// SGBM where its own checks accept a match, the network elsewhere (see the module docs).
pub struct FusedEngine {
    name: String,
    net: OnnxEngine,
    sgbm: SgbmEngine,
    size: (u32, u32),
    /// The pair at the network's resolution (a copy also when the sizes agree: the left-right check reuses it).
    net_left: Vec<u8>,
    net_right: Vec<u8>,
    net_disp: Vec<f32>,
    /// The network's disparity at the engine's resolution, in its pixels.
    up: Vec<f32>,
    sgbm_disp: Vec<f32>,
    scratch: Vec<f32>,
    sources: Vec<Source>,
    /// Largest SGBM range: 1.5x the network's range, below the image width.
    max_range: i32,
    range: i32,
}

fn cv(e: opencv::Error) -> RuntimeError {
    RuntimeError::Invalid(format!("fused: {}", e.message))
}

/// Resizes an 8-bit gray image (area averaging when shrinking, bilinear when enlarging).
pub(crate) fn resize_gray(src: &[u8], (sw, sh): (u32, u32), dst: &mut [u8], (dw, dh): (u32, u32)) -> Result<()> {
    if (sw, sh) == (dw, dh) {
        dst.copy_from_slice(src);
        return Ok(());
    }
    let s = Mat::new_rows_cols_with_data(sh as i32, sw as i32, src).map_err(cv)?;
    let mut d = Mat::default();
    let interp = if dw <= sw && dh <= sh { opencv::imgproc::INTER_AREA } else { opencv::imgproc::INTER_LINEAR };
    opencv::imgproc::resize(&s, &mut d, Size::new(dw as i32, dh as i32), 0.0, 0.0, interp).map_err(cv)?;
    dst.copy_from_slice(d.data_bytes().map_err(cv)?);
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

impl FusedEngine {
    /// The network `net` fused with SGBM at `width` x `height` (any size; the network's input is resized).
    pub fn new(net: OnnxEngine, width: u32, height: u32) -> Result<FusedEngine> {
        if width < 32 || height < 8 {
            return Err(RuntimeError::Invalid(format!("fused: {width}x{height} is too small for SGBM")));
        }
        let (mw, mh) = net.size();
        let sx = width as f64 / mw as f64;
        let below_width = (width as i32 - 16) / 16 * 16;
        let max_range =
            (((1.5 * net.max_disparity() * sx).ceil() as i32 + 15) / 16 * 16).clamp(16, below_width.max(16));
        let sgbm = SgbmEngine::new(width, height, max_range as f64)?;
        let n = (width * height) as usize;
        let m = (mw * mh) as usize;
        Ok(FusedEngine {
            name: format!("fused:{}+sgbm", net.manifest.variant),
            net,
            sgbm,
            size: (width, height),
            net_left: vec![0; m],
            net_right: vec![0; m],
            net_disp: vec![f32::NAN; m],
            up: vec![f32::NAN; n],
            sgbm_disp: vec![f32::NAN; n],
            scratch: Vec::with_capacity(n),
            sources: vec![Source::None; n],
            max_range,
            range: max_range,
        })
    }

    /// Where each pixel of the last result came from.
    pub fn sources(&self) -> &[Source] {
        &self.sources
    }

    /// The network's disparity of the last pair at the engine's resolution (engine pixels).
    pub fn network_disparity(&self) -> &[f32] {
        &self.up
    }

    /// SGBM's search range (px) in the last result.
    pub fn sgbm_range(&self) -> i32 {
        self.range
    }

    /// The network, with the last pair at its resolution and its disparity there (for a left-right check).
    pub fn network(&mut self) -> (&mut OnnxEngine, &[u8], &[u8], &[f32]) {
        (&mut self.net, &self.net_left, &self.net_right, &self.net_disp)
    }

    /// SGBM's range for the network's answer `up` (engine pixels).
    fn range_for(&mut self) -> i32 {
        self.scratch.clear();
        self.scratch.extend(self.up.iter().copied().filter(|v| v.is_finite()));
        if self.scratch.is_empty() {
            return self.max_range;
        }
        let k = ((self.scratch.len() - 1) as f64 * RANGE_QUANTILE) as usize;
        let (_, q, _) = self.scratch.select_nth_unstable_by(k, f32::total_cmp);
        let want = (1.2 * *q as f64 + 8.0).ceil() as i32;
        ((want + 15) / 16 * 16).clamp(16, self.max_range)
    }
}

impl DisparityEngine for FusedEngine {
    fn name(&self) -> &str {
        &self.name
    }
    fn size(&self) -> (u32, u32) {
        self.size
    }
    fn max_disparity(&self) -> f64 {
        self.max_range as f64
    }
    fn compute(&mut self, left: &[u8], right: &[u8], out: &mut [f32]) -> Result<()> {
        let n = (self.size.0 * self.size.1) as usize;
        if left.len() != n || right.len() != n || out.len() != n {
            return Err(RuntimeError::Invalid(format!(
                "{}: images of {} / {} pixels and output of {} for a {}x{} engine",
                self.name,
                left.len(),
                right.len(),
                out.len(),
                self.size.0,
                self.size.1
            )));
        }
        let msize = self.net.size();
        resize_gray(left, self.size, &mut self.net_left, msize)?;
        resize_gray(right, self.size, &mut self.net_right, msize)?;
        self.net.compute(&self.net_left, &self.net_right, &mut self.net_disp)?;
        let (ms, es) = ((msize.0 as usize, msize.1 as usize), (self.size.0 as usize, self.size.1 as usize));
        upsample_disparity(&self.net_disp, ms, &mut self.up, es);
        let range = self.range_for();
        if range != self.range {
            self.sgbm.set_range(range)?;
            self.range = range;
        }
        self.sgbm.compute(left, right, &mut self.sgbm_disp)?;
        for (((o, s), &sg), &nt) in out.iter_mut().zip(&mut self.sources).zip(&self.sgbm_disp).zip(&self.up) {
            (*o, *s) = if sg.is_finite() {
                (sg, Source::Sgbm)
            } else if nt.is_finite() {
                (nt, Source::Network)
            } else {
                (f32::NAN, Source::None)
            };
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
