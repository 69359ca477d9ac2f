//! Calibration files in OpenCV FileStorage YAML, read and written through OpenCV itself so that any OpenCV
//! program (and ROS camera_info tools) reads our files and we read theirs.
//!
//! Single camera (`abvs calib intrinsics`):
//! `image_width`, `image_height`, `camera_matrix` (3x3), `distortion_model` ("plumb_bob" | "rational_polynomial"
//! | "fisheye"), `distortion_coefficients` (OpenCV order), and when known `rms_px`, `image_names`,
//! `per_image_errors` (px, same order), `rejected_images`.
//!
//! Stereo pair at home (`abvs calib stereo`): maps `left` and `right` (each a single-camera block), `R` (3x3) and
//! `T` (3x1, **mm**) = T_lH^rH, mapping points from the left home camera frame to the right one
//! (x_r = R x_l + T, OpenCV stereoCalibrate's convention), and `rms_px`.
use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};
use opencv::core::{self, FileNode, FileNodeTraitConst, FileStorage, FileStorageTrait, FileStorageTraitConst, Mat};
use opencv::prelude::*;

use crate::model::{Camera, Distortion};

#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    #[error("{path}: cannot open calibration file: {message}")]
    Open { path: PathBuf, message: String },
    #[error("{path}: field `{field}`: {message}")]
    Field { path: PathBuf, field: String, message: String },
    #[error("{path}: OpenCV error: {message}")]
    OpenCv { path: PathBuf, message: String },
}

pub type Result<T> = std::result::Result<T, CameraError>;

/// Results of a calibration that are stored next to the model.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CalibInfo {
    pub rms_px: Option<f64>,
    pub image_names: Vec<String>,
    pub per_image_errors: Vec<f64>,
    pub rejected_images: Vec<String>,
}

/// Intrinsics of both eyes and T_lH^rH, from a stereo calibration at home.
#[derive(Clone, Debug, PartialEq)]
pub struct StereoCalibration {
    pub left: Camera,
    pub right: Camera,
    /// Rotation of T_lH^rH (left home camera -> right home camera).
    pub rotation: Matrix3<f64>,
    /// Translation of T_lH^rH in millimetres.
    pub translation_mm: Vector3<f64>,
    pub rms_px: Option<f64>,
}

impl StereoCalibration {
    /// T_lH^rH as an isometry in metres.
    pub fn left_to_right(&self) -> Isometry3<f64> {
        let r = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&self.rotation));
        Isometry3::from_parts(Translation3::from(self.translation_mm / 1000.0), r)
    }

    /// Baseline length (mm).
    pub fn baseline_mm(&self) -> f64 {
        self.translation_mm.norm()
    }

    pub fn read_yaml(path: impl AsRef<Path>) -> Result<StereoCalibration> {
        let path = path.as_ref();
        let fs = open(path, core::FileStorage_READ)?;
        let ctx = Ctx { path };
        let left = ctx.camera(&ctx.node(&fs, "left")?, "left.")?;
        let right = ctx.camera(&ctx.node(&fs, "right")?, "right.")?;
        let r = ctx.matrix(&ctx.node(&fs, "R")?, "R", 3, 3)?;
        let t = ctx.matrix(&ctx.node(&fs, "T")?, "T", 3, 1)?;
        let rotation = Matrix3::from_row_slice(&r);
        let det = rotation.determinant();
        let ortho = (rotation.transpose() * rotation - Matrix3::identity()).abs().max();
        if (det - 1.0).abs() > 1e-6 || ortho > 1e-6 {
            return Err(ctx.field("R", format!("not a rotation matrix (det {det:.6}, |R^T R - I| {ortho:.2e})")));
        }
        let rms_px = ctx.optional_real(&fs, "rms_px")?;
        Ok(StereoCalibration { left, right, rotation, translation_mm: Vector3::new(t[0], t[1], t[2]), rms_px })
    }

    pub fn write_yaml(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let mut fs = open(path, core::FileStorage_WRITE | core::FileStorage_FORMAT_YAML)?;
        let cv = |e: opencv::Error| CameraError::OpenCv { path: path.to_path_buf(), message: e.message };
        for (name, cam) in [("left", &self.left), ("right", &self.right)] {
            fs.start_write_struct(name, core::FileNode_MAP, "").map_err(cv)?;
            write_camera(&mut fs, cam, &CalibInfo::default()).map_err(cv)?;
            fs.end_write_struct().map_err(cv)?;
        }
        let r: Vec<Vec<f64>> = (0..3).map(|i| (0..3).map(|j| self.rotation[(i, j)]).collect()).collect();
        core::write_mat(&mut fs, "R", &Mat::from_slice_2d(&r).map_err(cv)?).map_err(cv)?;
        let t = vec![vec![self.translation_mm.x], vec![self.translation_mm.y], vec![self.translation_mm.z]];
        core::write_mat(&mut fs, "T", &Mat::from_slice_2d(&t).map_err(cv)?).map_err(cv)?;
        if let Some(rms) = self.rms_px {
            core::write_f64(&mut fs, "rms_px", rms).map_err(cv)?;
        }
        fs.release().map_err(cv)
    }
}

impl Camera {
    /// Reads a single-camera calibration file.
    pub fn read_yaml(path: impl AsRef<Path>) -> Result<Camera> {
        Ok(Camera::read_yaml_with_info(path)?.0)
    }

    /// Reads a single-camera calibration file and the stored calibration results.
    pub fn read_yaml_with_info(path: impl AsRef<Path>) -> Result<(Camera, CalibInfo)> {
        let path = path.as_ref();
        let fs = open(path, core::FileStorage_READ)?;
        let ctx = Ctx { path };
        let root = fs.root(0).map_err(|e| ctx.cv(e))?;
        let cam = ctx.camera(&root, "")?;
        let mut info = CalibInfo { rms_px: ctx.optional_real(&fs, "rms_px")?, ..Default::default() };
        let names = fs.get("image_names").map_err(|e| ctx.cv(e))?;
        if !names.is_none().map_err(|e| ctx.cv(e))? {
            info.image_names = ctx.strings(&names, "image_names")?;
        }
        let rejected = fs.get("rejected_images").map_err(|e| ctx.cv(e))?;
        if !rejected.is_none().map_err(|e| ctx.cv(e))? {
            info.rejected_images = ctx.strings(&rejected, "rejected_images")?;
        }
        let errors = fs.get("per_image_errors").map_err(|e| ctx.cv(e))?;
        if !errors.is_none().map_err(|e| ctx.cv(e))? {
            info.per_image_errors = ctx.values(&errors, "per_image_errors")?;
        }
        Ok((cam, info))
    }

    /// Writes a single-camera calibration file.
    pub fn write_yaml(&self, path: impl AsRef<Path>, info: &CalibInfo) -> Result<()> {
        let path = path.as_ref();
        let mut fs = open(path, core::FileStorage_WRITE | core::FileStorage_FORMAT_YAML)?;
        let cv = |e: opencv::Error| CameraError::OpenCv { path: path.to_path_buf(), message: e.message };
        write_camera(&mut fs, self, info).map_err(cv)?;
        fs.release().map_err(cv)
    }

    /// The 3x3 camera matrix as an OpenCV Mat (CV_64F).
    pub fn camera_matrix_mat(&self) -> opencv::Result<Mat> {
        Mat::from_slice_2d(&self.k_matrix())
    }

    /// The distortion coefficients as an OpenCV Mat (1xN, CV_64F), OpenCV order.
    pub fn distortion_mat(&self) -> opencv::Result<Mat> {
        Mat::from_slice_2d(&[self.distortion.coefficients()])
    }

    /// Builds a camera from OpenCV's calibration outputs.
    pub fn from_opencv(width: u32, height: u32, k: &Mat, dist: &Mat, model: &str) -> opencv::Result<Option<Camera>> {
        let kv = mat_values(k)?;
        let dv = mat_values(dist)?;
        if kv.len() != 9 {
            return Ok(None);
        }
        let Some(distortion) = Distortion::from_name(model, &dv) else { return Ok(None) };
        Ok(Some(Camera { width, height, fx: kv[0], fy: kv[4], cx: kv[2], cy: kv[5], distortion }))
    }
}

fn write_camera(fs: &mut FileStorage, cam: &Camera, info: &CalibInfo) -> opencv::Result<()> {
    core::write_i32(fs, "image_width", cam.width as i32)?;
    core::write_i32(fs, "image_height", cam.height as i32)?;
    core::write_mat(fs, "camera_matrix", &cam.camera_matrix_mat()?)?;
    core::write_str(fs, "distortion_model", cam.distortion.model_name())?;
    core::write_mat(fs, "distortion_coefficients", &cam.distortion_mat()?)?;
    if let Some(rms) = info.rms_px {
        core::write_f64(fs, "rms_px", rms)?;
    }
    if !info.image_names.is_empty() {
        fs.write_str_vec(
            "image_names",
            &core::Vector::<String>::from_iter(info.image_names.iter().map(String::as_str)),
        )?;
    }
    if !info.per_image_errors.is_empty() {
        let col: Vec<Vec<f64>> = info.per_image_errors.iter().map(|e| vec![*e]).collect();
        core::write_mat(fs, "per_image_errors", &Mat::from_slice_2d(&col)?)?;
    }
    if !info.rejected_images.is_empty() {
        fs.write_str_vec(
            "rejected_images",
            &core::Vector::<String>::from_iter(info.rejected_images.iter().map(String::as_str)),
        )?;
    }
    Ok(())
}

fn open(path: &Path, flags: i32) -> Result<FileStorage> {
    let err = |message: String| CameraError::Open { path: path.to_path_buf(), message };
    if flags == core::FileStorage_READ && !path.is_file() {
        // say what is there: /dev/null exists, it is just not a file to read a calibration from
        let why = match std::fs::metadata(path) {
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => "no such file".into(),
            Err(e) => e.to_string(),
            Ok(m) if m.is_dir() => "is a directory, expected a YAML file".into(),
            Ok(_) => "not a regular file (a device, pipe or socket), expected a YAML file".into(),
        };
        return Err(err(why));
    }
    let fs = FileStorage::new(path, flags, "").map_err(|e| err(e.message))?;
    if !fs.is_opened().map_err(|e| err(e.message))? {
        return Err(err("OpenCV could not open it".into()));
    }
    Ok(fs)
}

fn mat_values(m: &Mat) -> opencv::Result<Vec<f64>> {
    let mut d = Mat::default();
    m.convert_to(&mut d, core::CV_64F, 1.0, 0.0)?;
    let mut out = Vec::with_capacity((d.rows() * d.cols()) as usize);
    for r in 0..d.rows() {
        for c in 0..d.cols() {
            out.push(*d.at_2d::<f64>(r, c)?);
        }
    }
    Ok(out)
}

/// Error context: which file, and field paths inside it.
struct Ctx<'a> {
    path: &'a Path,
}

impl Ctx<'_> {
    fn cv(&self, e: opencv::Error) -> CameraError {
        CameraError::OpenCv { path: self.path.to_path_buf(), message: e.message }
    }
    fn field(&self, field: &str, message: String) -> CameraError {
        CameraError::Field { path: self.path.to_path_buf(), field: field.to_string(), message }
    }
    fn node(&self, fs: &FileStorage, name: &str) -> Result<FileNode> {
        let n = fs.get(name).map_err(|e| self.cv(e))?;
        if n.is_none().map_err(|e| self.cv(e))? {
            return Err(self.field(name, "missing".into()));
        }
        Ok(n)
    }
    fn child(&self, parent: &FileNode, name: &str, full: &str) -> Result<FileNode> {
        let n = parent.get(name).map_err(|e| self.cv(e))?;
        if n.is_none().map_err(|e| self.cv(e))? {
            return Err(self.field(full, "missing".into()));
        }
        Ok(n)
    }
    fn optional_real(&self, fs: &FileStorage, name: &str) -> Result<Option<f64>> {
        let n = fs.get(name).map_err(|e| self.cv(e))?;
        if n.is_none().map_err(|e| self.cv(e))? {
            return Ok(None);
        }
        if !(n.is_real().map_err(|e| self.cv(e))? || n.is_int().map_err(|e| self.cv(e))?) {
            return Err(self.field(name, "not a number".into()));
        }
        Ok(Some(n.real().map_err(|e| self.cv(e))?))
    }
    fn int(&self, parent: &FileNode, name: &str, full: &str) -> Result<i32> {
        let n = self.child(parent, name, full)?;
        if !n.is_int().map_err(|e| self.cv(e))? {
            return Err(self.field(full, "not an integer".into()));
        }
        n.to_i32().map_err(|e| self.cv(e))
    }
    fn matrix(&self, n: &FileNode, full: &str, rows: i32, cols: i32) -> Result<Vec<f64>> {
        let m = n.mat().map_err(|e| self.field(full, format!("not an opencv-matrix: {}", e.message)))?;
        if m.rows() * m.cols() != rows * cols {
            return Err(self.field(full, format!("expected {rows}x{cols}, found {}x{}", m.rows(), m.cols())));
        }
        let v = mat_values(&m).map_err(|e| self.cv(e))?;
        if let Some(i) = v.iter().position(|x| !x.is_finite()) {
            return Err(self.field(full, format!("element {i} is not finite")));
        }
        Ok(v)
    }
    fn values(&self, n: &FileNode, full: &str) -> Result<Vec<f64>> {
        if n.is_seq().map_err(|e| self.cv(e))? {
            let mut out = Vec::new();
            for i in 0..n.size().map_err(|e| self.cv(e))? {
                out.push(n.at(i as i32).and_then(|x| x.real()).map_err(|e| self.cv(e))?);
            }
            return Ok(out);
        }
        let m = n.mat().map_err(|e| self.field(full, format!("not a matrix or sequence: {}", e.message)))?;
        mat_values(&m).map_err(|e| self.cv(e))
    }
    fn strings(&self, n: &FileNode, full: &str) -> Result<Vec<String>> {
        if !n.is_seq().map_err(|e| self.cv(e))? {
            return Err(self.field(full, "not a sequence of strings".into()));
        }
        let mut out = Vec::new();
        for i in 0..n.size().map_err(|e| self.cv(e))? {
            out.push(n.at(i as i32).and_then(|x| x.string()).map_err(|e| self.cv(e))?);
        }
        Ok(out)
    }
    /// A camera block: the file root, or a `left` / `right` map of a stereo file (`prefix` names it in errors).
    fn camera(&self, node: &FileNode, prefix: &str) -> Result<Camera> {
        let f = |s: &str| format!("{prefix}{s}");
        if !node.is_map().map_err(|e| self.cv(e))? {
            let name = if prefix.is_empty() { "(root)".to_string() } else { prefix.trim_end_matches('.').to_string() };
            return Err(self.field(&name, "expected a map with image_width, image_height, camera_matrix, ...".into()));
        }
        let width = self.int(node, "image_width", &f("image_width"))?;
        let height = self.int(node, "image_height", &f("image_height"))?;
        if width <= 0 || height <= 0 {
            return Err(self.field(&f("image_width"), format!("image size {width}x{height} is not positive")));
        }
        let k = self.matrix(&self.child(node, "camera_matrix", &f("camera_matrix"))?, &f("camera_matrix"), 3, 3)?;
        if k[0] <= 0.0 || k[4] <= 0.0 || k[1] != 0.0 || k[3] != 0.0 || k[6] != 0.0 || k[7] != 0.0 || k[8] != 1.0 {
            return Err(self.field(
                &f("camera_matrix"),
                "expected [fx 0 cx; 0 fy cy; 0 0 1] with positive focal lengths (no skew)".into(),
            ));
        }
        let model_node = node.get("distortion_model").map_err(|e| self.cv(e))?;
        let model = if model_node.is_none().map_err(|e| self.cv(e))? {
            "plumb_bob".to_string()
        } else {
            model_node.string().map_err(|e| self.cv(e))?
        };
        let dn = self.child(node, "distortion_coefficients", &f("distortion_coefficients"))?;
        let d = self.values(&dn, &f("distortion_coefficients"))?;
        let distortion = Distortion::from_name(&model, &d).ok_or_else(|| {
            self.field(
                &f("distortion_coefficients"),
                format!(
                    "{} coefficients do not fit distortion_model `{model}` (fisheye: 4, plumb_bob: 4/5, \
                     rational_polynomial: 8)",
                    d.len()
                ),
            )
        })?;
        Ok(Camera { width: width as u32, height: height as u32, fx: k[0], fy: k[4], cx: k[2], cy: k[5], distortion })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camera_file_round_trips_through_opencv() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("cam.yaml");
        let cam = Camera::ov8856();
        let info = CalibInfo {
            rms_px: Some(0.21),
            image_names: vec!["a.png".into(), "b.png".into()],
            per_image_errors: vec![0.2, 0.25],
            rejected_images: vec!["c.png".into()],
        };
        cam.write_yaml(&p, &info).unwrap();
        let text = std::fs::read_to_string(&p).unwrap();
        assert!(text.starts_with("%YAML:1.0"), "{text}");
        assert!(text.contains("distortion_model: fisheye"));
        let (back, info2) = Camera::read_yaml_with_info(&p).unwrap();
        assert_eq!(back, cam);
        assert_eq!(info2, info);
    }

    #[test]
    fn stereo_file_round_trips() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("stereo.yaml");
        let rot = Rotation3::from_euler_angles(0.01, -0.02, 0.003).into_inner();
        let s = StereoCalibration {
            left: Camera::ov8856(),
            right: Camera::ov8856().scaled(1600, 1200),
            rotation: rot,
            translation_mm: Vector3::new(-65.0, 0.3, -0.2),
            rms_px: Some(0.3),
        };
        s.write_yaml(&p).unwrap();
        let back = StereoCalibration::read_yaml(&p).unwrap();
        assert!((back.rotation - rot).abs().max() < 1e-15);
        assert_eq!(back.left, s.left);
        assert_eq!(back.translation_mm, s.translation_mm);
        assert!((back.left_to_right().translation.vector.x + 0.065).abs() < 1e-12);
    }

    #[test]
    fn bad_files_name_the_field() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("bad.yaml");
        let e = Camera::read_yaml(&p).unwrap_err().to_string();
        assert!(e.contains("bad.yaml") && e.contains("no such file"), "{e}");
        std::fs::write(
            &p,
            "%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 500., 0., 320., 0., 500., 240., 0., 0., 1. ]\ndistortion_model: fisheye\ndistortion_coefficients: [0.1, 0.2]\n",
        )
        .unwrap();
        let e = Camera::read_yaml(&p).unwrap_err().to_string();
        assert!(e.contains("distortion_coefficients") && e.contains("2 coefficients"), "{e}");
        std::fs::write(&p, "%YAML:1.0\n---\nimage_width: 640\n").unwrap();
        let e = Camera::read_yaml(&p).unwrap_err().to_string();
        assert!(e.contains("image_height") && e.contains("missing"), "{e}");
        std::fs::write(&p, "%YAML:1.0\n---\nleft: 3\n").unwrap();
        let e = StereoCalibration::read_yaml(&p).unwrap_err().to_string();
        assert!(e.contains("`left`") && e.contains("expected a map"), "{e}");
    }

    /// The first fields of `left_intrinsics.yml` as OpenCV's calibration sample wrote it (Debian opencv-doc,
    /// examples/data): no `distortion_model` (plumb_bob is implied), five coefficients as a 5x1 matrix, and the
    /// sample's extra fields (nframes, board size, flags, reprojection errors), which the reader ignores.
    const OPENCV_SAMPLE_INTRINSICS: &str = "%YAML:1.0\n---\nnframes: 13\nimage_width: 640\nimage_height: 480\n\
        board_width: 9\nboard_height: 6\nsquare_size: 2.5000000372529030e-02\naspectRatio: 1.\nflags: 2\n\
        camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 5.3591573396163199e+02, 0., \
        3.4228315473308373e+02, 0.,\n       5.3591573396163199e+02, 2.3557082909788173e+02, 0., 0., 1. ]\n\
        distortion_coefficients: !!opencv-matrix\n   rows: 5\n   cols: 1\n   dt: d\n   data: [ \
        -2.6637260909660682e-01, -3.8588898922304653e-02,\n       1.7831947042852964e-03, \
        -2.8122100441115472e-04,\n       2.3839153080878486e-01 ]\n\
        avg_reprojection_error: 3.9259098975581364e-01\n\
        per_view_reprojection_errors: !!opencv-matrix\n   rows: 2\n   cols: 1\n   dt: f\n   data: [ \
        1.92965463e-01, 1.18204820e+00 ]\n";

    // The values exactly as OpenCV's sample file writes them.
    #[allow(clippy::excessive_precision)]
    fn check_opencv_sample(c: &Camera) {
        assert_eq!((c.width, c.height), (640, 480));
        assert_eq!((c.fx, c.fy), (5.3591573396163199e+02, 5.3591573396163199e+02));
        assert_eq!((c.cx, c.cy), (3.4228315473308373e+02, 2.3557082909788173e+02));
        assert_eq!(c.distortion.model_name(), "plumb_bob");
    }

    #[test]
    fn reads_intrinsics_written_by_opencvs_calibration_sample() {
        // Always run on the embedded copy (it used to be skipped, passing, when opencv-doc was not installed).
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("left_intrinsics.yml");
        std::fs::write(&p, OPENCV_SAMPLE_INTRINSICS).unwrap();
        check_opencv_sample(&Camera::read_yaml(&p).unwrap());
        // and the installed file itself where opencv-doc is (scripts/setup.sh installs it): the same camera
        let doc = Path::new("/usr/share/doc/opencv-doc/examples/data/left_intrinsics.yml");
        if doc.exists() {
            check_opencv_sample(&Camera::read_yaml(doc).unwrap());
        } else {
            eprintln!("{} not installed: checked the embedded copy only", doc.display());
        }
    }
}
