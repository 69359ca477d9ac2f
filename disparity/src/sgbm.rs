//! OpenCV's StereoSGBM (its parallel SGBM_3WAY mode), the classical engine: alone, and inside census-refine
//! (its prior) and the fused engine.
use opencv::core::{Mat, Scalar};
use opencv::prelude::*;

use crate::engine::{check_sizes, DisparityEngine};
use crate::error::{cv, DisparityError, Result};

/// OpenCV StereoSGBM with settings for our rectified eyes, in MODE_SGBM_3WAY: parallel stripes on OpenCV's
/// pool ([`crate::engine::set_opencv_threads`]) with MODE_SGBM's accuracy (plain MODE_SGBM runs on one thread).
pub struct SgbmEngine {
    width: u32,
    height: u32,
    num_disparities: i32,
    sgbm: opencv::core::Ptr<opencv::calib3d::StereoSGBM>,
    disp: Mat,
}

impl SgbmEngine {
    /// `max_disparity` is rounded up to OpenCV's multiple of 16.
    pub fn new(width: u32, height: u32, max_disparity: f64) -> Result<SgbmEngine> {
        Self::with_block(width, height, max_disparity, 5)
    }

    /// With a `block` x `block` matching window (P1 and P2 scale with its area, as OpenCV recommends).
    pub fn with_block(width: u32, height: u32, max_disparity: f64, block: i32) -> Result<SgbmEngine> {
        let cv = cv("sgbm");
        let num = ((max_disparity.ceil() as i32 + 15) / 16 * 16).max(16);
        let sgbm = opencv::calib3d::StereoSGBM::create(
            0,
            num,
            block,
            8 * block * block,
            32 * block * block,
            1,
            63,
            10,
            100,
            2,
            opencv::calib3d::StereoSGBM_MODE_SGBM_3WAY,
        )
        .map_err(&cv)?;
        let disp =
            Mat::new_rows_cols_with_default(height as i32, width as i32, opencv::core::CV_16SC1, Scalar::all(0.0))
                .map_err(&cv)?;
        Ok(SgbmEngine { width, height, num_disparities: num, sgbm, disp })
    }

    /// Changes the search range (px, a positive multiple of 16); the left `range` columns get no match.
    pub fn set_range(&mut self, range: i32) -> Result<()> {
        use opencv::calib3d::StereoMatcherTrait;
        if range < 16 || range % 16 != 0 {
            return Err(DisparityError::Invalid(format!("sgbm: range {range} is not a positive multiple of 16")));
        }
        self.sgbm.set_num_disparities(range).map_err(cv("sgbm"))?;
        self.num_disparities = range;
        Ok(())
    }
}

impl DisparityEngine for SgbmEngine {
    fn name(&self) -> &str {
        "sgbm"
    }
    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }
    fn max_disparity(&self) -> f64 {
        self.num_disparities as f64
    }
    fn compute(&mut self, left: &[u8], right: &[u8], out: &mut [f32]) -> Result<()> {
        check_sizes("sgbm", self.size(), left, right, out)?;
        let cv = cv("sgbm");
        let (w, h) = (self.width as i32, self.height as i32);
        let l = Mat::new_rows_cols_with_data(h, w, left).map_err(&cv)?;
        let r = Mat::new_rows_cols_with_data(h, w, right).map_err(&cv)?;
        use opencv::calib3d::StereoMatcherTrait;
        self.sgbm.compute(&l, &r, &mut self.disp).map_err(&cv)?;
        let d = self.disp.data_typed::<i16>().map_err(&cv)?;
        for (o, v) in out.iter_mut().zip(d) {
            // fixed point with 4 fractional bits; negative = no match
            *o = if *v < 0 { f32::NAN } else { *v as f32 / 16.0 };
        }
        Ok(())
    }
}
