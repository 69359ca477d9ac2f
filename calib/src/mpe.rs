//! The mean projection error (MPE) of the paper: AprilGrid corners seen at home, projected into
//! the current camera once with the model's pose and once with the measured pose; the error is
//! the mean pixel distance between the two projections.
//!
//! Target layout (documented, fixed): four Kalibr AprilGrids (6 x 6 tag36h11 tags of 88 mm,
//! spacing 0.3: 144 tag corners per board) facing the eye 1.5 m in front of the
//! home camera, centred at (+-450, +-350) mm. Camera: the OV8856 as an ideal pinhole,
//! 1600 x 1200 px, 118 deg horizontal field of view (fx = fy = 800 / tan 59 deg = 480.7 px),
//! principal point at the centre. Corners outside the measured view are not counted.
use abvs_eye::Pose;
use nalgebra::Vector3;

#[derive(Debug, Clone)]
pub struct Target {
    /// Corner positions in the home camera frame (mm).
    pub corners: Vec<Vector3<f64>>,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: f64,
    pub height: f64,
}

impl Default for Target {
    fn default() -> Self {
        Target::paper()
    }
}

impl Target {
    /// The four-board layout described in the module doc.
    pub fn paper() -> Self {
        let (tag, gap) = (88.0, 0.3 * 88.0);
        let pitch = tag + gap;
        let size = 6.0 * tag + 5.0 * gap;
        let mut corners = Vec::new();
        for (bx, by) in [(-450.0, -350.0), (450.0, -350.0), (-450.0, 350.0), (450.0, 350.0)] {
            for i in 0..6 {
                for j in 0..6 {
                    for (dx, dy) in [(0.0, 0.0), (tag, 0.0), (tag, tag), (0.0, tag)] {
                        let x = bx - size / 2.0 + j as f64 * pitch + dx;
                        let y = by - size / 2.0 + i as f64 * pitch + dy;
                        corners.push(Vector3::new(x, y, 1500.0));
                    }
                }
            }
        }
        let f = 800.0 / 59f64.to_radians().tan();
        Target { corners, fx: f, fy: f, cx: 800.0, cy: 600.0, width: 1600.0, height: 1200.0 }
    }

    /// Pixel of a home-frame point seen from camera pose `cam` (relative to home).
    fn project(&self, cam: &Pose, x: &Vector3<f64>) -> Option<(f64, f64)> {
        let p = cam.r.transpose() * (x - cam.t);
        if p.z <= 1.0 {
            return None;
        }
        Some((self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy))
    }

    /// Mean pixel distance between projections with the predicted and the measured pose, over
    /// the corners inside the measured image; NaN if none is visible.
    pub fn projection_error_px(&self, pred: &Pose, meas: &Pose) -> f64 {
        let (mut sum, mut n) = (0.0, 0usize);
        for x in &self.corners {
            let Some(m) = self.project(meas, x) else { continue };
            if m.0 < 0.0 || m.0 >= self.width || m.1 < 0.0 || m.1 >= self.height {
                continue;
            }
            if let Some(p) = self.project(pred, x) {
                sum += ((p.0 - m.0).powi(2) + (p.1 - m.1).powi(2)).sqrt();
                n += 1;
            }
        }
        if n == 0 {
            f64::NAN
        } else {
            sum / n as f64
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use abvs_eye::Fick;

    #[test]
    fn zero_for_equal_poses_and_grows_with_error() {
        let t = Target::paper();
        assert_eq!(t.corners.len(), 4 * 144);
        let a = Pose::new(Fick::from_deg([10.0, -5.0, 20.0]).to_matrix(), Vector3::new(1.0, 2.0, 3.0));
        assert_eq!(t.projection_error_px(&a, &a), 0.0);
        let b = Pose::new(Fick::from_deg([10.1, -5.0, 20.0]).to_matrix(), a.t);
        let e = t.projection_error_px(&b, &a);
        // 0.1 deg at ~480 px/rad focal: ~0.84 px at the centre, more towards the edges.
        assert!(e > 0.7 && e < 1.5, "{e}");
    }

    #[test]
    fn boards_visible_over_the_workspace() {
        let t = Target::paper();
        for p in [[30.0, 15.0, 30.0], [-30.0, -15.0, -30.0], [0.0, 0.0, 0.0]] {
            let a = Pose::new(Fick::from_deg(p).to_matrix(), Vector3::zeros());
            assert!(t.projection_error_px(&a, &a).is_finite(), "{p:?}");
        }
    }
}
