//! Stereo calibration at home: both intrinsics (each with outlier rejection) and T_lH^rH, the
//! transform mapping points from the left home camera frame to the right one (OpenCV
//! stereoCalibrate's R, T; T in mm).
use crate::detect::Detection;
use crate::error::{CamcalError, Result};
use crate::intrinsics::{calibrate, camera_matrix, dist_coeffs, views, CalibOptions, Calibrated, Model};
use crate::target::Target;
use opencv::calib3d;
use opencv::core::{Mat, Point2d, Point2f, Point3d, Point3f, Size, TermCriteria, TermCriteria_Type, Vector, CV_64F};
use opencv::prelude::*;

/// Result of a stereo calibration.
#[derive(Debug, Clone)]
pub struct StereoResult {
    pub left: Calibrated,
    pub right: Calibrated,
    /// Rotation of T_lH^rH (x_r = R x_l + T).
    pub rotation: [[f64; 3]; 3],
    pub translation_mm: [f64; 3],
    /// RMS reprojection error of the stereo fit (both cameras), px.
    pub rms_px: f64,
    /// Image pairs used by the stereo fit.
    pub pairs_used: usize,
}

/// Calibrates a stereo pair from detections of the same target in image pairs (`left[i]` and
/// `right[i]` taken at the same time; `None` where an image failed).
pub fn calibrate_stereo(
    left: &[Option<Detection>],
    right: &[Option<Detection>],
    target: &Target,
    model: Model,
    min_corners: usize,
    opts: &CalibOptions,
) -> Result<StereoResult> {
    if left.len() != right.len() {
        return Err(CamcalError::Invalid(format!("{} left and {} right images", left.len(), right.len())));
    }
    let size_of = |d: &[Option<Detection>]| d.iter().flatten().map(|x| (x.width, x.height)).next();
    let (wl, hl) = size_of(left).ok_or_else(|| CamcalError::Calibration("no left image read".into()))?;
    let (wr, hr) = size_of(right).ok_or_else(|| CamcalError::Calibration("no right image read".into()))?;
    let cl = calibrate(&views(left, target, min_corners), wl, hl, model, opts)?;
    let cr = calibrate(&views(right, target, min_corners), wr, hr, model, opts)?;
    let kept = |c: &Calibrated, i: usize| c.per_image.iter().any(|p| p.0 == i);

    // common corners of each (pair, board) kept on both sides
    let mut obj: Vector<Vector<Point3f>> = Vector::new();
    let mut p1: Vector<Vector<Point2f>> = Vector::new();
    let mut p2: Vector<Vector<Point2f>> = Vector::new();
    let mut pairs = std::collections::BTreeSet::new();
    for (i, (l, r)) in left.iter().zip(right).enumerate() {
        let (Some(l), Some(r)) = (l, r) else { continue };
        if !kept(&cl, i) || !kept(&cr, i) {
            continue;
        }
        for (board, lc) in l.by_board(target) {
            let (mut o, mut a, mut b) = (Vector::new(), Vector::new(), Vector::new());
            for c in &lc {
                if let Some(rc) = r.corners.iter().find(|x| x.id == c.id) {
                    let p = target.corner(c.id).1;
                    o.push(Point3f::new(p.x as f32, p.y as f32, p.z as f32));
                    a.push(Point2f::new(c.px[0] as f32, c.px[1] as f32));
                    b.push(Point2f::new(rc.px[0] as f32, rc.px[1] as f32));
                }
            }
            let _ = board;
            if o.len() >= min_corners {
                obj.push(o);
                p1.push(a);
                p2.push(b);
                pairs.insert(i);
            }
        }
    }
    if obj.is_empty() {
        return Err(CamcalError::Calibration("no image pair sees a board in both cameras".into()));
    }
    if model == Model::Fisheye {
        // cv::fisheye::stereoCalibrate needs the same number of points in every view: keep the
        // views with the most common corners (whole boards), or cut all to the smallest view.
        let (obj2, a2, b2) = equal_size_views(&obj, &p1, &p2, 3)?;
        (obj, p1, p2) = (obj2, a2, b2);
    }
    let (mut k1, mut d1) = (camera_matrix(&cl.camera)?, dist_coeffs(&cl.camera)?);
    let (mut k2, mut d2) = (camera_matrix(&cr.camera)?, dist_coeffs(&cr.camera)?);
    let crit = TermCriteria::new((TermCriteria_Type::COUNT as i32) | (TermCriteria_Type::EPS as i32), 100, 1e-10)?;
    let size = Size::new(wl as i32, hl as i32);
    let (mut r, mut t) = (Mat::default(), Mat::default());
    let rms = match model {
        // cv::fisheye wants double-precision points (with floats an internal fixed-size copy
        // asserts in OpenCV 4.6).
        Model::Fisheye => calib3d::fisheye_stereo_calibrate(
            &to_f64_3(&obj)?,
            &to_f64_2(&p1)?,
            &to_f64_2(&p2)?,
            &mut k1,
            &mut d1,
            &mut k2,
            &mut d2,
            size,
            &mut r,
            &mut t,
            calib3d::Fisheye_CALIB_FIX_INTRINSIC,
            crit,
        ),
        _ => {
            let (mut e, mut f) = (Mat::default(), Mat::default());
            calib3d::stereo_calibrate(
                &obj,
                &p1,
                &p2,
                &mut k1,
                &mut d1,
                &mut k2,
                &mut d2,
                size,
                &mut r,
                &mut t,
                &mut e,
                &mut f,
                calib3d::CALIB_FIX_INTRINSIC,
                crit,
            )
        }
    }
    .map_err(|e| CamcalError::Calibration(format!("stereo: {e}")))?;
    let mut r64 = Mat::default();
    r.convert_to(&mut r64, CV_64F, 1.0, 0.0)?;
    let mut t64 = Mat::default();
    t.convert_to(&mut t64, CV_64F, 1.0, 0.0)?;
    let t64 = t64.reshape(1, 3)?;
    let mut rotation = [[0.0; 3]; 3];
    for (i, row) in rotation.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = *r64.at_2d::<f64>(i as i32, j as i32)?;
        }
    }
    let translation_mm = [*t64.at_2d::<f64>(0, 0)?, *t64.at_2d::<f64>(1, 0)?, *t64.at_2d::<f64>(2, 0)?];
    Ok(StereoResult { left: cl, right: cr, rotation, translation_mm, rms_px: rms, pairs_used: pairs.len() })
}

fn to_f64_3(v: &Vector<Vector<Point3f>>) -> Result<Vector<Mat>> {
    let mut out = Vector::new();
    for o in v.iter() {
        let p: Vec<Point3d> = o.iter().map(|p| Point3d::new(p.x as f64, p.y as f64, p.z as f64)).collect();
        out.push(Mat::from_slice(&p)?.try_clone()?);
    }
    Ok(out)
}

fn to_f64_2(v: &Vector<Vector<Point2f>>) -> Result<Vector<Mat>> {
    let mut out = Vector::new();
    for o in v.iter() {
        let p: Vec<Point2d> = o.iter().map(|p| Point2d::new(p.x as f64, p.y as f64)).collect();
        out.push(Mat::from_slice(&p)?.try_clone()?);
    }
    Ok(out)
}

type Views = (Vector<Vector<Point3f>>, Vector<Vector<Point2f>>, Vector<Vector<Point2f>>);

/// Views of equal size: those with the largest point count if there are at least `min_views`,
/// else every view cut to the smallest count.
fn equal_size_views(
    obj: &Vector<Vector<Point3f>>,
    p1: &Vector<Vector<Point2f>>,
    p2: &Vector<Vector<Point2f>>,
    min_views: usize,
) -> Result<Views> {
    let lens: Vec<usize> = obj.iter().map(|o| o.len()).collect();
    let max = lens.iter().copied().max().unwrap_or(0);
    let full: Vec<usize> = (0..lens.len()).filter(|&i| lens[i] == max).collect();
    let (keep, n): (Vec<usize>, usize) = if full.len() >= min_views {
        (full, max)
    } else {
        ((0..lens.len()).collect(), lens.iter().copied().min().unwrap_or(0))
    };
    let cut3 = |v: Vector<Point3f>| -> Vector<Point3f> { v.iter().take(n).collect() };
    let cut2 = |v: Vector<Point2f>| -> Vector<Point2f> { v.iter().take(n).collect() };
    let mut out: Views = (Vector::new(), Vector::new(), Vector::new());
    for i in keep {
        out.0.push(cut3(obj.get(i)?));
        out.1.push(cut2(p1.get(i)?));
        out.2.push(cut2(p2.get(i)?));
    }
    Ok(out)
}
