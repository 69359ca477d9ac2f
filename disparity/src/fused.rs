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
//!
//! Its left-right check ([`DisparityEngine::own_lr_check`], the one definition of `abvs disparity --engine
//! fused --confidence` and of `abvs run --engine fused` with `[disparity] confidence`): SGBM's matches passed
//! its own left-right check already, and two independent matchers that agree are surer than one, so an SGBM
//! pixel scores `0.5 (1 + exp(-|d_sgbm - d_network| / 2 px))` in [0.5, 1]; the network's pixels get the
//! generic check ([`crate::confidence::lr_check`]) at the network's resolution, scaled below every accepted
//! SGBM match: `0.5 exp(-|d_left - d_right|)`, and fail (reason and, with `invalidate`, NaN) where it fails.
use crate::confidence::{lr_check_with_reasons, mirror_rows, reason};
use crate::engine::{check_sizes, DisparityEngine};
use crate::error::{DisparityError, Result};
use crate::onnx::OnnxEngine;
use crate::resample::{nearest_centred, resize_gray, upsample_disparity};
use crate::sgbm::SgbmEngine;

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
    /// The left-right check's buffers, sized at its first run (nothing per frame after it): the mirrored
    /// pair, its disparity, the right view, the network's checked map, confidence and reasons at the
    /// network's resolution, then at the engine's.
    mirror: [Vec<u8>; 2],
    mirror_disp: Vec<f32>,
    right_disp: Vec<f32>,
    check_disp: Vec<f32>,
    check_conf: (Vec<f32>, Vec<f32>),
    check_why: (Vec<u8>, Vec<u8>),
}

/// The fused engine's confidence scale for network pixels: below every accepted SGBM match, which is right
/// to a fraction of a pixel where the network is not.
pub const NETWORK_CONFIDENCE: f32 = 0.5;

/// Scale (px) of the fused engine's agreement between SGBM and the network: at the bad-2 threshold the two
/// agree to exp(-1).
pub const AGREEMENT_PX: f32 = 2.0;

impl FusedEngine {
    /// The network `net` fused with SGBM at `width` x `height` (any size; the network's input is resized).
    pub fn new(net: OnnxEngine, width: u32, height: u32) -> Result<FusedEngine> {
        if width < 32 || height < 8 {
            return Err(DisparityError::Invalid(format!("fused: {width}x{height} is too small for SGBM")));
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
            mirror: [Vec::new(), Vec::new()],
            mirror_disp: Vec::new(),
            right_disp: Vec::new(),
            check_disp: Vec::new(),
            check_conf: (Vec::new(), Vec::new()),
            check_why: (Vec::new(), Vec::new()),
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
        check_sizes(&self.name, self.size, left, right, out)?;
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
    fn own_lr_check(
        &mut self,
        max_diff: f32,
        invalidate: bool,
        disparity: &mut [f32],
        conf: &mut [f32],
        why: &mut [u8],
    ) -> Option<Result<usize>> {
        Some(self.lr_check(max_diff, invalidate, disparity, conf, why))
    }
}

impl FusedEngine {
    /// The fused engine's left-right check of its last answer `disparity` (see the module docs).
    fn lr_check(
        &mut self,
        max_diff: f32,
        invalidate: bool,
        disparity: &mut [f32],
        conf: &mut [f32],
        why: &mut [u8],
    ) -> Result<usize> {
        let n = (self.size.0 * self.size.1) as usize;
        if disparity.len() != n || conf.len() != n || why.len() != n {
            return Err(DisparityError::Invalid(format!("{}: left-right check of a map not its size", self.name)));
        }
        let (mw, mh) = (self.net.size().0 as usize, self.net.size().1 as usize);
        let m = mw * mh;
        if self.right_disp.len() != m {
            self.mirror = [vec![0; m], vec![0; m]];
            self.mirror_disp = vec![f32::NAN; m];
            self.right_disp = vec![f32::NAN; m];
            self.check_disp = vec![f32::NAN; m];
            self.check_conf = (vec![0.0; m], vec![0.0; n]);
            self.check_why = (vec![reason::VALID; m], vec![reason::VALID; n]);
        }
        // the network's right view: the mirrored right image is a left view of the mirrored left one
        let [ml, mr] = &mut self.mirror;
        mirror_rows(&self.net_right, mw, ml);
        mirror_rows(&self.net_left, mw, mr);
        self.net.compute(ml, mr, &mut self.mirror_disp)?;
        mirror_rows(&self.mirror_disp, mw, &mut self.right_disp);
        self.check_disp.copy_from_slice(&self.net_disp);
        let ((c_net, net_conf), (w_net, net_why)) = (&mut self.check_conf, &mut self.check_why);
        lr_check_with_reasons(&mut self.check_disp, &self.right_disp, mw, max_diff, false, c_net, Some(w_net));
        let isize = (self.size.0 as usize, self.size.1 as usize);
        nearest_centred(w_net, (mw, mh), net_why, isize);
        nearest_centred(c_net, (mw, mh), net_conf, isize);
        let mut passed = 0;
        for (i, s) in self.sources.iter().enumerate() {
            (conf[i], why[i]) = match s {
                // two independent matchers that agree are surer than one
                Source::Sgbm => {
                    let agree = (-(disparity[i] - self.up[i]).abs() / AGREEMENT_PX).exp();
                    (NETWORK_CONFIDENCE * (1.0 + if agree.is_finite() { agree } else { 0.0 }), reason::VALID)
                }
                // a network pixel is never as sure as an accepted SGBM match
                Source::Network if net_why[i] == reason::VALID => (NETWORK_CONFIDENCE * net_conf[i], reason::VALID),
                Source::Network => {
                    if invalidate {
                        disparity[i] = f32::NAN;
                    }
                    (0.0, net_why[i])
                }
                Source::None => (0.0, reason::NO_ESTIMATE),
            };
            passed += (why[i] == reason::VALID) as usize;
        }
        Ok(passed)
    }
}
