//! Intrinsic calibration from detections: OpenCV fisheye (Kannala-Brandt), pinhole (plumb bob)
//! or rational models; per-image reprojection errors; outlier images (error far above the
//! median) dropped and the calibration redone.
use crate::detect::Detection;
use crate::error::{CamcalError, Result};
use crate::target::Target;
use abvs_camera::{Camera, Distortion};
use opencv::calib3d;
use opencv::core::{Mat, Point2f, Point3f, Size, TermCriteria, TermCriteria_Type, Vec3d, Vector, CV_64F};
use opencv::prelude::*;
use std::str::FromStr;

/// Lens model of a calibration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Model {
    /// OpenCV fisheye (Kannala-Brandt, k1..k4).
    Fisheye,
    /// OpenCV pinhole with plumb-bob distortion (k1, k2, p1, p2, k3).
    #[cfg_attr(feature = "clap", value(alias = "plumb_bob"))]
    Pinhole,
    /// OpenCV rational model (k1, k2, p1, p2, k3, k4, k5, k6).
    #[cfg_attr(feature = "clap", value(alias = "rational_polynomial"))]
    Rational,
}

impl FromStr for Model {
    type Err = CamcalError;
    fn from_str(s: &str) -> Result<Model> {
        match s {
            "fisheye" => Ok(Model::Fisheye),
            "pinhole" | "plumb_bob" => Ok(Model::Pinhole),
            "rational" | "rational_polynomial" => Ok(Model::Rational),
            _ => Err(CamcalError::Invalid(format!("model '{s}': expected fisheye, pinhole or rational"))),
        }
    }
}

impl Model {
    /// The model of a camera (an undistorted camera counts as pinhole).
    pub fn of(cam: &Camera) -> Model {
        match cam.distortion {
            Distortion::Fisheye(_) => Model::Fisheye,
            Distortion::Rational(_) => Model::Rational,
            _ => Model::Pinhole,
        }
    }
    /// The distortion_model name of the YAML files.
    pub fn name(self) -> &'static str {
        match self {
            Model::Fisheye => "fisheye",
            Model::Pinhole => "plumb_bob",
            Model::Rational => "rational_polynomial",
        }
    }
}

/// OpenCV camera matrix of a camera.
pub fn camera_matrix(cam: &Camera) -> Result<Mat> {
    Ok(cam.camera_matrix_mat()?)
}

/// OpenCV distortion coefficients of a camera (4 for fisheye, 5 or 8 otherwise), as a column:
/// cv::fisheye copies them into a fixed 4x1 `Vec4d`, which refuses a 1x4 row.
pub fn dist_coeffs(cam: &Camera) -> Result<Mat> {
    let c = cam.distortion.coefficients();
    let row = Mat::from_slice(&c)?;
    Ok(row.reshape(1, row.cols())?.try_clone()?)
}

fn camera_from_mats(model: Model, width: u32, height: u32, k: &Mat, d: &Mat) -> Result<Camera> {
    let d = d.reshape(1, 1)?.try_clone()?;
    Camera::from_opencv(width, height, k, &d, model.name())?
        .ok_or_else(|| CamcalError::Calibration(format!("OpenCV returned no valid {} camera", model.name())))
}

fn project_view(cam: &Camera, obj: &Vector<Point3f>, rvec: &Mat, tvec: &Mat) -> Result<Vec<[f64; 2]>> {
    let mut img: Vector<Point2f> = Vector::new();
    let k = camera_matrix(cam)?;
    let d = dist_coeffs(cam)?;
    match Model::of(cam) {
        Model::Fisheye => {
            let mut jac = Mat::default();
            calib3d::fisheye_project_points_vec(obj, &mut img, rvec, tvec, &k, &d, 0.0, &mut jac)?
        }
        _ => calib3d::project_points_def(obj, rvec, tvec, &k, &d, &mut img)?,
    }
    Ok(img.iter().map(|p| [p.x as f64, p.y as f64]).collect())
}

/// One calibration view: the corners of one board in one image (a planar view, as OpenCV's
/// calibration functions want).
#[derive(Debug, Clone)]
pub struct View {
    /// Index of the image in the caller's list.
    pub image: usize,
    pub board: u32,
    pub ids: Vec<u32>,
    pub object: Vector<Point3f>,
    pub pixels: Vector<Point2f>,
}

/// Splits detections into planar views with at least `min_corners` corners each.
pub fn views(dets: &[Option<Detection>], target: &Target, min_corners: usize) -> Vec<View> {
    let mut out = Vec::new();
    for (i, d) in dets.iter().enumerate() {
        let Some(d) = d else { continue };
        for (board, cs) in d.by_board(target) {
            if cs.len() < min_corners {
                continue;
            }
            let object = cs
                .iter()
                .map(|c| {
                    let p = target.corner(c.id).1;
                    Point3f::new(p.x as f32, p.y as f32, p.z as f32)
                })
                .collect();
            let pixels = cs.iter().map(|c| Point2f::new(c.px[0] as f32, c.px[1] as f32)).collect();
            out.push(View { image: i, board, ids: cs.iter().map(|c| c.id).collect(), object, pixels });
        }
    }
    out
}

/// Options of [`calibrate`].
#[derive(Debug, Clone, Copy)]
pub struct CalibOptions {
    /// An image is an outlier when its RMS error exceeds `outlier_factor` x the median ...
    pub outlier_factor: f64,
    /// ... and this many pixels.
    pub outlier_floor_px: f64,
    /// Rounds of drop-and-recalibrate.
    pub max_rounds: usize,
    /// Fewest images left after rejection.
    pub min_images: usize,
}

impl Default for CalibOptions {
    fn default() -> Self {
        CalibOptions { outlier_factor: 3.0, outlier_floor_px: 0.3, max_rounds: 3, min_images: 3 }
    }
}

/// Result of an intrinsic calibration.
#[derive(Debug, Clone)]
pub struct Calibrated {
    pub camera: Camera,
    /// RMS reprojection error over all corners of the kept images, px.
    pub rms_px: f64,
    /// (image index, RMS px) of every kept image.
    pub per_image: Vec<(usize, f64)>,
    /// (image index, RMS px at the time it was dropped) of the dropped outliers.
    pub dropped: Vec<(usize, f64)>,
    /// Board poses of the kept views (rvec, tvec mm), same order as `views`.
    pub views: Vec<View>,
    pub extrinsics: Vec<([f64; 3], [f64; 3])>,
}

fn criteria() -> Result<TermCriteria> {
    Ok(TermCriteria::new((TermCriteria_Type::COUNT as i32) | (TermCriteria_Type::EPS as i32), 100, 1e-10)?)
}

fn vec3(m: &Mat) -> Result<[f64; 3]> {
    let m = if m.typ() == CV_64F { m.try_clone()? } else { conv64(m)? };
    let m = m.reshape(1, 3)?;
    Ok([*m.at_2d::<f64>(0, 0)?, *m.at_2d::<f64>(1, 0)?, *m.at_2d::<f64>(2, 0)?])
}

fn conv64(m: &Mat) -> Result<Mat> {
    let mut o = Mat::default();
    m.convert_to(&mut o, CV_64F, 1.0, 0.0)?;
    Ok(o)
}

/// One calibration of `views` (no rejection). Returns intrinsics, extrinsics per view.
fn calibrate_once(
    views: &[View],
    width: u32,
    height: u32,
    model: Model,
) -> Result<(Camera, Vec<([f64; 3], [f64; 3])>)> {
    let obj: Vector<Vector<Point3f>> = views.iter().map(|v| v.object.clone()).collect();
    let img: Vector<Vector<Point2f>> = views.iter().map(|v| v.pixels.clone()).collect();
    let size = Size::new(width as i32, height as i32);
    let mut k = Mat::eye(3, 3, CV_64F)?.to_mat()?;
    let mut rvecs: Vector<Mat> = Vector::new();
    let mut tvecs: Vector<Mat> = Vector::new();
    let (d, res) = match model {
        Model::Fisheye => {
            let mut d = Mat::zeros(4, 1, CV_64F)?.to_mat()?;
            let flags = calib3d::Fisheye_CALIB_RECOMPUTE_EXTRINSIC | calib3d::Fisheye_CALIB_FIX_SKEW;
            let mut rv: Vector<Vec3d> = Vector::new();
            let mut tv: Vector<Vec3d> = Vector::new();
            let mut r = calib3d::calibrate(&obj, &img, size, &mut k, &mut d, &mut rv, &mut tv, flags, criteria()?);
            if r.is_err() {
                // OpenCV starts a fisheye from f = size / pi and, with that, cannot undistort a board seen near
                // the border (boards close to the camera) to find its first pose: start instead from the
                // views that stay in the centre, then fit every view from there
                let central = central_views(views, width, height);
                if central.len() >= 3 && central.len() < views.len() {
                    let (guess, _) = calibrate_once(&central, width, height, model)?;
                    k = camera_matrix(&guess)?;
                    d = dist_coeffs(&guess)?;
                    let flags = flags | calib3d::Fisheye_CALIB_USE_INTRINSIC_GUESS;
                    (rv, tv) = (Vector::new(), Vector::new());
                    r = calib3d::calibrate(&obj, &img, size, &mut k, &mut d, &mut rv, &mut tv, flags, criteria()?);
                }
            }
            for (a, b) in rv.iter().zip(tv.iter()) {
                rvecs.push(Mat::from_slice(&[a[0], a[1], a[2]])?.try_clone()?);
                tvecs.push(Mat::from_slice(&[b[0], b[1], b[2]])?.try_clone()?);
            }
            (d, r)
        }
        Model::Pinhole | Model::Rational => {
            let (n, flags) = if model == Model::Rational { (8, calib3d::CALIB_RATIONAL_MODEL) } else { (5, 0) };
            let mut d = Mat::zeros(n, 1, CV_64F)?.to_mat()?;
            let r =
                calib3d::calibrate_camera(&obj, &img, size, &mut k, &mut d, &mut rvecs, &mut tvecs, flags, criteria()?);
            (d, r)
        }
    };
    res.map_err(|e| CamcalError::Calibration(format!("{model:?}: {e}")))?;
    let intr = camera_from_mats(model, width, height, &k, &d)?;
    let mut ext = Vec::with_capacity(views.len());
    for (r, t) in rvecs.iter().zip(tvecs.iter()) {
        ext.push((vec3(&r)?, vec3(&t)?));
    }
    Ok((intr, ext))
}

/// The views whose corners all lie within half the image's height of its centre.
fn central_views(views: &[View], width: u32, height: u32) -> Vec<View> {
    let (cx, cy, r) = (0.5 * width as f32, 0.5 * height as f32, 0.5 * height as f32);
    views.iter().filter(|v| v.pixels.iter().all(|p| (p.x - cx).hypot(p.y - cy) <= r)).cloned().collect()
}

/// Squared reprojection errors of each view's corners.
pub fn view_sq_errors(intr: &Camera, view: &View, rvec: &[f64; 3], tvec: &[f64; 3]) -> Result<Vec<f64>> {
    let r = Mat::from_slice(rvec)?.try_clone()?;
    let t = Mat::from_slice(tvec)?.try_clone()?;
    let proj = project_view(intr, &view.object, &r, &t)?;
    Ok(proj
        .iter()
        .zip(view.pixels.iter())
        .map(|(p, q)| (p[0] - q.x as f64).powi(2) + (p[1] - q.y as f64).powi(2))
        .collect())
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Calibrates from planar views with outlier-image rejection.
pub fn calibrate(all_views: &[View], width: u32, height: u32, model: Model, opts: &CalibOptions) -> Result<Calibrated> {
    let mut views: Vec<View> = all_views.to_vec();
    let mut dropped = Vec::new();
    for round in 0..=opts.max_rounds {
        let mut images: Vec<usize> = views.iter().map(|v| v.image).collect();
        images.dedup();
        images.sort();
        images.dedup();
        if images.len() < opts.min_images {
            return Err(CamcalError::Calibration(format!(
                "{} usable images, need at least {}",
                images.len(),
                opts.min_images
            )));
        }
        let (intr, ext) = calibrate_once(&views, width, height, model)?;
        // per image: sum of squared errors and count
        let mut acc: Vec<(usize, f64, usize)> = images.iter().map(|&i| (i, 0.0, 0)).collect();
        let (mut tot, mut cnt) = (0.0, 0usize);
        for (v, (r, t)) in views.iter().zip(&ext) {
            let e = view_sq_errors(&intr, v, r, t)?;
            let a = acc.iter_mut().find(|a| a.0 == v.image).expect("image listed");
            a.1 += e.iter().sum::<f64>();
            a.2 += e.len();
            tot += e.iter().sum::<f64>();
            cnt += e.len();
        }
        let per_image: Vec<(usize, f64)> = acc.iter().map(|&(i, s, n)| (i, (s / n as f64).sqrt())).collect();
        let rms_px = (tot / cnt as f64).sqrt();
        let med = median(&mut per_image.iter().map(|p| p.1).collect::<Vec<_>>());
        let thr = (opts.outlier_factor * med).max(opts.outlier_floor_px);
        let bad: Vec<(usize, f64)> = per_image.iter().copied().filter(|p| p.1 > thr).collect();
        if bad.is_empty() || round == opts.max_rounds || images.len() - bad.len() < opts.min_images {
            return Ok(Calibrated { camera: intr, rms_px, per_image, dropped, views, extrinsics: ext });
        }
        views.retain(|v| !bad.iter().any(|b| b.0 == v.image));
        dropped.extend(bad);
    }
    unreachable!("the last round returns")
}
