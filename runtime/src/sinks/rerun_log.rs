//! Logs what the runtime sees to a rerun recording (`abvs run --rerun out.rrd`, cargo feature
//! `rerun`): both moving cameras as frustums with their rectified images, the left depth image and
//! the point cloud, on the timeline `capture` (frame mid-exposure, CLOCK_MONOTONIC) and `frame`.
//!
//! Entity tree, all in the left home camera frame (OpenCV's x right, y down, z forward):
//! ```text
//! world                    the left home camera (view coordinates RDF)
//! world/cloud              Points3D, gray from the rectified left image
//! world/left               Transform3D: current left camera -> left home (T_rel,l)
//! world/left/rectified     Transform3D: rectified -> current left; Pinhole; image; depth
//! world/right              Transform3D: current right camera -> left home (T_rel,l . (T_l^r)^-1)
//! world/right/rectified    Transform3D; Pinhole; image
//! ```
use std::path::Path;

use abvs_eye::Pose;
use rerun::{RecordingStream, RecordingStreamBuilder};

use abvs_runtime_core::error::{Result, RuntimeError};
use abvs_runtime_core::messages::Published;
use abvs_runtime_core::sink::Sink;
use abvs_runtime_core::stats::RunStats;

/// Logs every published frame (rectified pair, depth, cloud, camera frustums) to a rerun `.rrd` file.
pub struct RerunSink {
    rec: RecordingStream,
    path: std::path::PathBuf,
    frames: u64,
    errors: u64,
    /// Reused per frame (the cloud's positions and colours).
    positions: Vec<[f32; 3]>,
    colors: Vec<[u8; 3]>,
}

fn err(path: &Path, e: impl std::fmt::Display) -> RuntimeError {
    RuntimeError::File { path: path.to_path_buf(), line: None, msg: format!("rerun: {e}") }
}

fn transform(p: &Pose) -> rerun::Transform3D {
    let m = p.r.cast::<f32>();
    let cols =
        [[m[(0, 0)], m[(1, 0)], m[(2, 0)]], [m[(0, 1)], m[(1, 1)], m[(2, 1)]], [m[(0, 2)], m[(1, 2)], m[(2, 2)]]];
    let t = [p.t.x as f32, p.t.y as f32, p.t.z as f32];
    rerun::Transform3D::from_translation_mat3x3(t, rerun::datatypes::Mat3x3::from(cols))
}

impl RerunSink {
    /// Creates `path` (an .rrd file the rerun viewer opens).
    pub fn create(path: &Path) -> Result<RerunSink> {
        let rec = RecordingStreamBuilder::new("abvs").save(path).map_err(|e| err(path, e))?;
        rec.log_static("world", &rerun::ViewCoordinates::RDF()).map_err(|e| err(path, e))?;
        Ok(RerunSink { rec, path: path.to_path_buf(), frames: 0, errors: 0, positions: vec![], colors: vec![] })
    }

    fn log(&mut self, out: &Published) -> std::result::Result<(), rerun::RecordingStreamError> {
        let rec = &self.rec;
        rec.set_time_sequence("frame", out.seq as i64);
        rec.set_time("capture", rerun::TimeCell::from_duration_nanos(out.t_frame_ns));
        let (w, h) = (out.cam.width, out.cam.height);
        let pinhole = rerun::Pinhole::from_focal_length_and_resolution([out.cam.f as f32; 2], [w as f32, h as f32])
            .with_principal_point([out.cam.cx as f32, out.cam.cy as f32])
            .with_camera_xyz(rerun::components::ViewCoordinates::RDF)
            .with_image_plane_distance(0.1);
        let right_in_home = out.pose.rel_left.compose(&out.pose.left_to_right.inverse());
        for (name, cam_in_home, rect_from_cam, image) in [
            ("left", out.pose.rel_left, out.rect.rect_from_left, out.left_rect),
            ("right", right_in_home, out.rect.rect_from_right, out.right_rect),
        ] {
            rec.log(format!("world/{name}"), &transform(&cam_in_home))?;
            let cam_from_rect = Pose::new(rect_from_cam.transpose(), nalgebra::Vector3::zeros());
            rec.log(format!("world/{name}/rectified"), &transform(&cam_from_rect))?;
            rec.log(format!("world/{name}/rectified"), &pinhole)?;
            rec.log(format!("world/{name}/rectified/image"), &rerun::Image::from_l8(image.to_vec(), [w, h]))?;
        }
        let depth_bytes: Vec<u8> = out.depth.depth.iter().flat_map(|d| d.to_le_bytes()).collect();
        rec.log(
            "world/left/rectified/depth",
            &rerun::DepthImage::from_data_type_and_bytes(depth_bytes, [w, h], rerun::datatypes::ChannelDatatype::F32)
                .with_meter(1.0),
        )?;
        let n = out.depth.n_points;
        self.positions.clear();
        self.colors.clear();
        let cloud = &out.depth.cloud[..n];
        self.positions.extend(cloud.iter().map(|p| [p.x, p.y, p.z]));
        self.colors.extend(cloud.iter().map(|p| [p.gray(); 3]));
        rec.log(
            "world/cloud",
            &rerun::Points3D::new(self.positions.iter().copied())
                .with_colors(self.colors.iter().map(|c| rerun::Color::from_rgb(c[0], c[1], c[2])))
                .with_radii([0.002f32]),
        )?;
        Ok(())
    }
}

impl Sink for RerunSink {
    fn name(&self) -> &'static str {
        "rerun"
    }

    fn consume(&mut self, out: &Published) -> Result<()> {
        // Viewing is best effort: a failing log is counted, the pipeline goes on.
        match self.log(out) {
            Ok(()) => self.frames += 1,
            Err(e) => {
                self.errors += 1;
                if self.errors == 1 {
                    return Err(err(&self.path, e));
                }
            }
        }
        Ok(())
    }

    fn finish(&mut self, stats: &mut RunStats) {
        if let Err(e) = self.rec.flush_blocking() {
            self.errors += 1;
            log::error!("{}", err(&self.path, e));
        }
        stats.extra.insert(
            "rerun".into(),
            serde_json::json!({"file": self.path.display().to_string(), "frames": self.frames, "errors": self.errors}),
        );
    }
}
