//! The engines' one interface, at the bottom of the crate: every engine ([`crate::onnx`], [`crate::sgbm`],
//! [`crate::census`], [`crate::fused`]) implements [`DisparityEngine`], and the confidence and the
//! left-right check ([`crate::confidence`]) run any of them.
//!
//! Invalid disparities are NaN (never 0, which is a valid disparity at infinity).
use crate::error::{cv, DisparityError, Result};

/// A stereo matcher on rectified 8-bit gray images of a fixed size.
pub trait DisparityEngine: Send {
    /// The engine's name in statistics and logs.
    fn name(&self) -> &str;
    /// The resolution the engine runs at.
    fn size(&self) -> (u32, u32);
    /// Largest disparity the engine searches (px).
    fn max_disparity(&self) -> f64;
    /// Left-view disparity (px) into `out` (width*height); NaN where there is none.
    fn compute(&mut self, left: &[u8], right: &[u8], out: &mut [f32]) -> Result<()>;
    /// The last [`DisparityEngine::compute`]'s per-pixel confidence in [0, 1] and the reason code of each
    /// ([`crate::confidence::reason`]), when the engine computes them as it goes (census-refine:
    /// [`crate::census_confidence`]); width*height each.
    fn confidence(&self) -> Option<(&[f32], &[u8])> {
        None
    }
    /// The left-right check of the last [`DisparityEngine::compute`]'s answer `disparity`, for an engine
    /// that defines its own (the fused engine: [`crate::fused::FusedEngine`]); `None` for the others, which
    /// [`crate::confidence::LrCheck`] checks by running them on the mirrored pair. Writes each pixel's
    /// confidence and reason; with `invalidate` every pixel that fails loses its disparity (NaN). Returns
    /// how many pixels passed.
    fn own_lr_check(
        &mut self,
        _max_diff: f32,
        _invalidate: bool,
        _disparity: &mut [f32],
        _conf: &mut [f32],
        _why: &mut [u8],
    ) -> Option<Result<usize>> {
        None
    }
}

/// Refuses images or an output whose sizes are not the engine's.
pub(crate) fn check_sizes(name: &str, (w, h): (u32, u32), left: &[u8], right: &[u8], out: &[f32]) -> Result<()> {
    let n = (w * h) as usize;
    if left.len() != n || right.len() != n || out.len() != n {
        return Err(DisparityError::Invalid(format!(
            "{name}: images of {} / {} pixels and output of {} for a {w}x{h} engine",
            left.len(),
            right.len(),
            out.len()
        )));
    }
    Ok(())
}

/// OpenCV's worker threads (one pool per process: SGBM_3WAY's stripes, remap): the same budget as the
/// network's intra-op threads, so that the two engines are compared and deployed on equal terms.
pub fn set_opencv_threads(threads: usize) -> Result<()> {
    opencv::core::set_num_threads(threads.max(1) as i32).map_err(cv("opencv threads"))
}

/// Runs an engine on a pair already at its resolution, into a new map.
pub fn compute(e: &mut dyn DisparityEngine, left: &[u8], right: &[u8]) -> Result<Vec<f32>> {
    let (w, h) = e.size();
    let mut d = vec![f32::NAN; (w * h) as usize];
    e.compute(left, right, &mut d)?;
    Ok(d)
}
