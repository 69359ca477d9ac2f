//! tag36h11 detection with the AprilTag 3 library itself (C, built from the source vendored by
//! the crates.io crate `apriltag-sys`, statically linked). Its gradient-cluster quad finder and
//! decoder read tags down to ~12 px wide that OpenCV 4.6's aruco misses, so it is the detector for
//! stand-alone tags ([`crate::detect::apriltags`]). Corners come in AprilTag/Kalibr order.
use apriltag_sys as sys;

use crate::error::{CamcalError, Result};

/// One decoded tag.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tag {
    pub id: u32,
    /// Corners (px, pixel centres at integers) in AprilTag order.
    pub corners: [[f64; 2]; 4],
    /// Bits corrected by the decoder (0 = exact code).
    pub hamming: u32,
    pub decision_margin: f32,
}

/// Detector settings (AprilTag 3's names).
#[derive(Debug, Clone, Copy)]
pub struct Options {
    /// 1.0 = quads searched at full resolution (small tags); 2.0 is ~4x faster but loses them.
    pub quad_decimate: f32,
    /// Snap the quad edges to strong gradients. Off: on the real test photos it moved tiny tags'
    /// corners by up to 3 px and lost one tag (the library's own test set is made without it).
    pub refine_edges: bool,
    /// Most bits the decoder may correct (the library's default, 2; tag36h11's codes are at least
    /// 11 bits apart, so 2 corrected bits still leave 7 of margin against a false decode).
    pub max_hamming: u32,
    pub threads: u32,
}

impl Default for Options {
    fn default() -> Self {
        Options { quad_decimate: 1.0, refine_edges: false, max_hamming: 2, threads: 2 }
    }
}

/// Owns the C detector and family (freed on drop).
struct Detector {
    td: *mut sys::apriltag_detector_t,
    tf: *mut sys::apriltag_family_t,
}

impl Drop for Detector {
    fn drop(&mut self) {
        // SAFETY: both were created by the library's constructors below and are freed once.
        unsafe {
            sys::apriltag_detector_destroy(self.td);
            sys::tag36h11_destroy(self.tf);
        }
    }
}

/// Detects every tag36h11 tag in an 8-bit gray image (`width` x `height`, row-major, tightly packed).
pub fn detect_tag36h11(gray: &[u8], width: usize, height: usize, opts: &Options) -> Result<Vec<Tag>> {
    if gray.len() != width * height || width == 0 || height == 0 {
        return Err(CamcalError::Invalid(format!("{} bytes for a {width}x{height} image", gray.len())));
    }
    let (w, h) = (i32::try_from(width), i32::try_from(height));
    let (Ok(w), Ok(h)) = (w, h) else {
        return Err(CamcalError::Invalid(format!("image {width}x{height} too large")));
    };
    // SAFETY: constructors return owned pointers (checked non-null); the image struct borrows
    // `gray` only for the duration of `apriltag_detector_detect`, which does not keep it; the
    // detections array is read and then freed by the library's destructor.
    unsafe {
        let det = Detector { td: sys::apriltag_detector_create(), tf: sys::tag36h11_create() };
        if det.td.is_null() || det.tf.is_null() {
            return Err(CamcalError::Invalid("AprilTag detector allocation failed".into()));
        }
        sys::apriltag_detector_add_family_bits(det.td, det.tf, opts.max_hamming as i32);
        (*det.td).quad_decimate = opts.quad_decimate;
        (*det.td).refine_edges = opts.refine_edges;
        (*det.td).nthreads = opts.threads.max(1) as i32;
        let mut im = sys::image_u8_t { width: w, height: h, stride: w, buf: gray.as_ptr() as *mut u8 };
        let arr = sys::apriltag_detector_detect(det.td, &mut im);
        if arr.is_null() {
            return Err(CamcalError::Invalid("AprilTag detection failed".into()));
        }
        let n = (*arr).size.max(0) as usize;
        let mut out = Vec::with_capacity(n);
        for k in 0..n {
            let d: *mut sys::apriltag_detection_t = *((*arr).data as *const *mut sys::apriltag_detection_t).add(k);
            let d = &*d;
            out.push(Tag {
                id: d.id as u32,
                corners: d.p,
                hamming: d.hamming as u32,
                decision_margin: d.decision_margin,
            });
        }
        sys::apriltag_detections_destroy(arr);
        out.sort_by_key(|t| t.id);
        Ok(out)
    }
}
