//! Corner detection with sub-pixel accuracy: AprilGrids (OpenCV aruco DICT_APRILTAG_36h11 +
//! cornerSubPix on the grid's saddle points, or the pure-Rust `aprilgrid` crate) and chessboards
//! (OpenCV findChessboardCorners + cornerSubPix).
use crate::error::{CamcalError, Result};
use crate::saddle;
use crate::target::{AprilGridSpec, ChessboardSpec, Target};
use opencv::core::{Mat, Point2f, Ptr, Size, TermCriteria, TermCriteria_Type, Vector};
use opencv::prelude::*;
use opencv::{aruco, calib3d, imgcodecs, imgproc};
use std::path::Path;

/// One detected corner: global corner id (see [`crate::target`]) and pixel position
/// (OpenCV convention: pixel centres at integer coordinates).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Corner {
    pub id: u32,
    pub px: [f64; 2],
}

/// The corners found in one image, sorted by id.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Detection {
    pub width: u32,
    pub height: u32,
    pub corners: Vec<Corner>,
}

impl Detection {
    /// Corners grouped by board (board index, corners), boards in increasing order.
    pub fn by_board(&self, target: &Target) -> Vec<(u32, Vec<Corner>)> {
        let mut out: Vec<(u32, Vec<Corner>)> = Vec::new();
        for c in &self.corners {
            let b = target.corner(c.id).0;
            match out.iter_mut().find(|(bb, _)| *bb == b) {
                Some((_, v)) => v.push(*c),
                None => out.push((b, vec![*c])),
            }
        }
        out.sort_by_key(|(b, _)| *b);
        out
    }
}

/// Which AprilTag detector to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum AprilDetector {
    /// OpenCV aruco (DICT_APRILTAG_36h11, 2-bit border, AprilTag quad finder) + cornerSubPix on
    /// the saddle points.
    #[cfg_attr(feature = "clap", value(name = "opencv"))]
    OpenCv,
    /// The crates.io `aprilgrid` crate (pure Rust, saddle-point based): the default, it finds
    /// every tag of a Kalibr grid (see camcal/README.md).
    #[default]
    #[cfg_attr(feature = "clap", value(name = "aprilgrid"))]
    AprilGridCrate,
}

/// Reads an image as 8-bit grayscale.
pub fn load_gray(path: &Path) -> Result<Mat> {
    let p = path.to_str().ok_or_else(|| CamcalError::ImageRead { path: path.into(), msg: "non-UTF-8 path".into() })?;
    if !path.is_file() {
        return Err(CamcalError::ImageRead { path: path.into(), msg: "no such file".into() });
    }
    let m = imgcodecs::imread(p, imgcodecs::IMREAD_GRAYSCALE)?;
    if m.empty() {
        return Err(CamcalError::ImageRead { path: path.into(), msg: "not a decodable image".into() });
    }
    Ok(m)
}

/// [`load_gray`] and [`detect`] of every file, the files spread over the machine's cores (each image is
/// independent; a 75-pair `abvs calib stereo` took 39 instead of 46 s on two cores): `out[i]` is `files[i]`'s,
/// whatever order they finished in. `done` is called once per image, from the thread that detected it (progress).
pub fn detect_files(
    files: &[impl AsRef<Path> + Sync],
    target: &Target,
    detector: AprilDetector,
    done: &(dyn Fn() + Sync),
) -> Vec<Result<Detection>> {
    use std::sync::atomic::{AtomicUsize, Ordering};
    let workers = std::thread::available_parallelism().map_or(1, |n| n.get()).min(files.len());
    let next = AtomicUsize::new(0);
    let mut out: Vec<Option<Result<Detection>>> = files.iter().map(|_| None).collect();
    std::thread::scope(|s| {
        let work = || {
            let mut mine = Vec::new();
            loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some(f) = files.get(i) else { break mine };
                mine.push((i, load_gray(f.as_ref()).and_then(|g| detect(&g, target, detector))));
                done();
            }
        };
        let handles: Vec<_> = (0..workers).map(|_| s.spawn(work)).collect();
        for h in handles {
            for (i, r) in h.join().unwrap_or_else(|e| std::panic::resume_unwind(e)) {
                out[i] = Some(r);
            }
        }
    });
    // every index below files.len() was taken by exactly one worker, and every worker was joined
    out.into_iter().map(|r| r.expect("an image no worker detected")).collect()
}

/// A grayscale Mat from 8-bit pixels (row-major).
pub fn gray_mat(width: usize, height: usize, pixels: &[u8]) -> Result<Mat> {
    if pixels.len() != width * height {
        return Err(CamcalError::Invalid(format!("{} pixels for {width}x{height}", pixels.len())));
    }
    let m = Mat::from_slice(pixels)?;
    Ok(m.reshape(1, height as i32)?.try_clone()?)
}

fn criteria() -> Result<TermCriteria> {
    Ok(TermCriteria::new((TermCriteria_Type::COUNT as i32) | (TermCriteria_Type::EPS as i32), 60, 1e-4)?)
}

/// Detects the corners of `target` in a grayscale image.
pub fn detect(gray: &Mat, target: &Target, detector: AprilDetector) -> Result<Detection> {
    match target {
        Target::AprilGrid(g) => match detector {
            AprilDetector::OpenCv => detect_aprilgrid_opencv(gray, g),
            AprilDetector::AprilGridCrate => detect_aprilgrid_crate(gray, g),
        },
        Target::Chessboard(c) => detect_chessboard(gray, c),
    }
}

fn size_of(gray: &Mat) -> (u32, u32) {
    (gray.cols() as u32, gray.rows() as u32)
}

fn apriltag_dictionary() -> Result<Ptr<aruco::Dictionary>> {
    Ok(aruco::get_predefined_dictionary(aruco::PREDEFINED_DICTIONARY_NAME::DICT_APRILTAG_36h11)?)
}

/// OpenCV's DICT_APRILTAG_36h11 stores each code rotated by 180 deg relative to the AprilTag
/// library (and Kalibr), so the marker's own top-left, top-right, bottom-right, bottom-left are
/// the upright tag's bottom-right, bottom-left, top-left, top-right. Returns the AprilTag /
/// Kalibr order: bottom-left, bottom-right, top-right, top-left (checked against AprilTag 3's
/// own output on real photos in tests/apriltag_photos.rs).
fn aruco_to_apriltag_order(c: [[f64; 2]; 4]) -> [[f64; 2]; 4] {
    [c[1], c[0], c[3], c[2]]
}

/// Raw tag detections of OpenCV's aruco module: (tag id, corners in Kalibr order k = 0..4:
/// bottom-left, bottom-right, top-right, top-left of the upright tag), before refinement.
pub fn opencv_tags(gray: &Mat) -> Result<Vec<(u32, [[f64; 2]; 4])>> {
    let mut params = aruco::DetectorParameters::create()?;
    params.set_marker_border_bits(2);
    params.set_min_distance_to_border(0);
    // Each tag touches the grid's corner squares diagonally, which merges their contours in
    // aruco's contour finder; AprilTag 3's gradient-cluster quad finder (the APRILTAG corner
    // mode) separates some of them (see camcal/README.md for the recall this gives).
    params.set_corner_refinement_method(3);
    detect_tags(gray, &params)
}

/// tag36h11 detections of aruco with `params`, corners mapped to the AprilTag/Kalibr order.
fn detect_tags(gray: &Mat, params: &opencv::core::Ptr<aruco::DetectorParameters>) -> Result<Vec<(u32, [[f64; 2]; 4])>> {
    let dict = apriltag_dictionary()?;
    let mut corners: Vector<Vector<Point2f>> = Vector::new();
    let mut ids: Vector<i32> = Vector::new();
    let mut rejected: Vector<Vector<Point2f>> = Vector::new();
    aruco::detect_markers(gray, &dict, &mut corners, &mut ids, params, &mut rejected)?;
    let mut out = Vec::with_capacity(ids.len());
    for (id, c) in ids.iter().zip(corners.iter()) {
        if id < 0 || c.len() != 4 {
            continue;
        }
        let p = |i: usize| -> [f64; 2] {
            let q = c.get(i).unwrap_or_default();
            [q.x as f64, q.y as f64]
        };
        let mut c = aruco_to_apriltag_order([p(0), p(1), p(2), p(3)]);
        if params.corner_refinement_method() == 3 {
            // aruco's AprilTag refinement is a port of AprilTag 3 and keeps its pixel convention
            // (found on the real photos: exactly (+0.5, +0.5) px from OpenCV's).
            c = c.map(|q| [q[0] - APRILTAG_PIXEL_OFFSET, q[1] - APRILTAG_PIXEL_OFFSET]);
        }
        out.push((id as u32, c));
    }
    Ok(out)
}

/// Stand-alone tag36h11 tags (1-bit border, as printed by the AprilTag tools): OpenCV aruco with
/// its AprilTag corner refinement (CORNER_REFINE_APRILTAG). Corners in the AprilTag library's
/// order (counter-clockwise in the image starting bottom-left of the upright tag), so they
/// compare directly with that library's output.
pub fn apriltags_opencv(gray: &Mat) -> Result<Vec<(u32, [[f64; 2]; 4])>> {
    let mut params = aruco::DetectorParameters::create()?;
    params.set_marker_border_bits(1);
    params.set_corner_refinement_method(3); // CORNER_REFINE_APRILTAG (AprilTag 3's quad finder)
                                            // small tags (~25 px), tags near the border and tags close to each other (faces of a cube)
    params.set_min_marker_perimeter_rate(0.01);
    params.set_min_distance_to_border(0);
    params.set_min_marker_distance_rate(0.001);
    params.set_min_corner_distance_rate(0.01);
    params.set_perspective_remove_pixel_per_cell(8);
    params.set_min_otsu_std_dev(2.0);
    detect_tags(gray, &params)
}

/// Stand-alone tag36h11 tags with the AprilTag 3 library (finds tags down to ~12 px that aruco
/// misses; see camcal/README.md), corners in AprilTag order and OpenCV's pixel convention.
pub fn apriltags(gray: &Mat) -> Result<Vec<(u32, [[f64; 2]; 4])>> {
    apriltag3_tags(gray)
}

/// AprilTag 3 detections (up to 2 corrected bits), corners moved from the library's pixel
/// convention (top-left pixel centre at (0.5, 0.5)) to OpenCV's (at (0, 0)).
fn apriltag3_tags(gray: &Mat) -> Result<Vec<(u32, [[f64; 2]; 4])>> {
    let (w, h) = size_of(gray);
    let pixels =
        if gray.is_continuous() { gray.data_bytes()?.to_vec() } else { gray.try_clone()?.data_bytes()?.to_vec() };
    let tags = crate::apriltag3::detect_tag36h11(&pixels, w as usize, h as usize, &Default::default())?;
    Ok(tags
        .into_iter()
        .map(|t| (t.id, t.corners.map(|p| [p[0] - APRILTAG_PIXEL_OFFSET, p[1] - APRILTAG_PIXEL_OFFSET])))
        .collect())
}

/// AprilTag 3 puts the top-left pixel's centre at (0.5, 0.5) (its bilinear sampler reads pixel
/// `floor(x - 0.5)`); OpenCV and this project at (0, 0).
pub const APRILTAG_PIXEL_OFFSET: f64 = 0.5;

/// AprilGrid corners with OpenCV: aruco finds the tags (outer corners of their black border,
/// which are the grid's saddle points), then [`refine_grid_corners`].
pub fn detect_aprilgrid_opencv(gray: &Mat, _spec: &AprilGridSpec) -> Result<Detection> {
    refine_grid_corners(gray, opencv_tags(gray)?)
}

/// Grid corners from tag detections (any detector: id, corners in Kalibr order): every tag corner
/// is a saddle point of the grid, refined by [`crate::saddle`] (iterated quadratic fit on a patch
/// scaled to the tag) as corner 4 id + k. A corner whose refinement does not converge near the
/// detector's estimate is left out (it then counts as not found).
pub fn refine_grid_corners(gray: &Mat, tags: Vec<(u32, [[f64; 2]; 4])>) -> Result<Detection> {
    let (width, height) = size_of(gray);
    let mut corners = Vec::new();
    for (id, c) in saddle::refine_tags(gray, &tags)? {
        for (k, p) in c.iter().enumerate() {
            if let Some(px) = p {
                corners.push(Corner { id: 4 * id + k as u32, px: *px });
            }
        }
    }
    corners.sort_by_key(|c| c.id);
    corners.dedup_by_key(|c| c.id);
    Ok(Detection { width, height, corners })
}

/// Converts a grayscale Mat to an `image` crate image.
pub fn mat_to_image(gray: &Mat) -> Result<image::GrayImage> {
    let (w, h) = size_of(gray);
    let cont = gray.try_clone()?;
    let bytes = cont.data_bytes()?.to_vec();
    image::GrayImage::from_raw(w, h, bytes).ok_or_else(|| CamcalError::Invalid("image buffer size".into()))
}

/// AprilGrid corners with the `aprilgrid` crate (Kalibr grids, 2-bit border): it finds and decodes
/// the tags ([`aprilgrid_crate_tags`]); its own one-shot sub-pixel step is biased (see
/// [`crate::saddle`]), so the corners go through [`refine_grid_corners`].
pub fn detect_aprilgrid_crate(gray: &Mat, spec: &AprilGridSpec) -> Result<Detection> {
    refine_grid_corners(gray, aprilgrid_crate_tags(gray, spec)?)
}

/// The `aprilgrid` crate's tags (id, corners in Kalibr order, the crate's own sub-pixel estimate).
pub fn aprilgrid_crate_tags(gray: &Mat, spec: &AprilGridSpec) -> Result<Vec<(u32, [[f64; 2]; 4])>> {
    let img = image::DynamicImage::ImageLuma8(mat_to_image(gray)?);
    let params = aprilgrid::detector::DetectorParams {
        tag_spacing_ratio: spec.spacing as f32,
        max_num_of_boards: 16,
        ..aprilgrid::detector::DetectorParams::default_params()
    };
    let det = aprilgrid::detector::TagDetector::new(&aprilgrid::TagFamily::T36H11, Some(params));
    let mut tags: Vec<(u32, [[f64; 2]; 4])> = det
        .detect(&img)
        .into_iter()
        .map(|(id, c)| {
            let mut k = [[0.0; 2]; 4];
            for (j, p) in c.iter().enumerate() {
                k[CRATE_ORDER[j] as usize] = [p.0 as f64, p.1 as f64];
            }
            (id, k)
        })
        .collect();
    tags.sort_by_key(|t| t.0);
    Ok(tags)
}

/// Kalibr corner index of the aprilgrid crate's j-th corner (checked against OpenCV on rendered
/// grids in the tests).
const CRATE_ORDER: [u32; 4] = [0, 1, 2, 3];

/// Chessboard inner corners: findChessboardCorners (adaptive threshold, normalised) then
/// cornerSubPix (11x11 window, as OpenCV's calibration sample).
pub fn detect_chessboard(gray: &Mat, spec: &ChessboardSpec) -> Result<Detection> {
    let (width, height) = size_of(gray);
    let mut v: Vector<Point2f> = Vector::new();
    let flags = calib3d::CALIB_CB_ADAPTIVE_THRESH | calib3d::CALIB_CB_NORMALIZE_IMAGE;
    let found = calib3d::find_chessboard_corners(gray, Size::new(spec.cols as i32, spec.rows as i32), &mut v, flags)?;
    if !found || v.len() != spec.cols * spec.rows {
        return Ok(Detection { width, height, corners: vec![] });
    }
    imgproc::corner_sub_pix(gray, &mut v, Size::new(11, 11), Size::new(-1, -1), criteria()?)?;
    let corners = v.iter().enumerate().map(|(i, p)| Corner { id: i as u32, px: [p.x as f64, p.y as f64] }).collect();
    Ok(Detection { width, height, corners })
}
