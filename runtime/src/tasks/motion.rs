//! Eyes that move while they expose: row timing, per-row rotations and the motion gate.
//!
//! conventions.md "Time": row r of a frame starting at `t_start` has its mid-exposure at
//! `t_start + r * readout / (H - 1) + exposure / 2`; the frame's instant is its middle row's. The OV8856
//! reads a frame out in ~32 ms, so at 100 deg/s the first and last rows see the eye 3 deg apart.
//!
//! The correction: every row is mapped into the **virtual camera**, the eye as it was at the frame's
//! instant. For a node b of `bands + 1` nodes down the image (row `b (H - 1) / bands`) the align stage
//! interpolates the link angles at that row's mid-exposure, the kinematics stage turns them into the
//! camera's rotation `R_b` (calibrated FK, the frame's motion history frozen), and
//! `R_b^T R_frame` takes a ray of the virtual camera into the camera as it was when that row exposed.
//! Rectification ([`crate::tasks::rectify`]) projects each output pixel through the rotation of the row
//! it lands on (interpolated between nodes, solved by fixed-point iteration: the row depends on the
//! rotation only weakly), so both eyes' rectified images are those of global-shutter cameras at the
//! frame's instant, and depth is placed with that instant's pose. Only rotation is corrected: the
//! optical centre moves by well under a millimetre during a readout at pursuit speeds (the camera sits
//! near the SPM's centre), a parallax below 0.1 px at the working range.
//!
//! The gate: from the encoders the runtime knows each eye's angular speed at the frame's instant and so
//! the blur (speed x exposure) in rectified pixels. A frame above the threshold is published with its
//! depth invalid (NaN) and an empty cloud, its header flagged, never as valid depth: as an eye does
//! during a saccade (saccadic suppression). See `DEFAULT_GATE_BLUR_PX` for the default's reason.
use nalgebra::Matrix3;

#[cfg(test)]
use abvs_runtime_core::params::MotionConfig;

/// Half the interval (s) of the central difference that gives an eye's angular speed: two encoder
/// periods at 1 kHz, short against a pursuit's changes, long against the counts' quantisation
/// (0.004 deg / 2 ms = 2 deg/s).
pub const SPEED_DT_S: f64 = 1e-3;

/// Half the window (s) over which an eye's mean angular velocity is taken before and after the frame's
/// instant: about half a readout, so the two tell whether the eye moved steadily while the rows exposed (the
/// self-check's timing evidence is first order in the speed and needs that). Within the encoder margin the
/// align stage already waits for (20 ms past the last row), so it adds no latency.
pub const WIDE_DT_S: f64 = 0.015;

/// Camera time (ns) of node `b` of `bands`: that row's mid-exposure, relative to the frame's instant
/// `t_frame_ns` (the middle row's).
pub fn node_time_ns(t_frame_ns: i64, readout_ns: i64, b: usize, bands: usize) -> i64 {
    t_frame_ns - readout_ns / 2 + (readout_ns as i128 * b as i128 / bands.max(1) as i128) as i64
}

/// Rotation angle (deg) between two rotation matrices.
pub fn angle_deg(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    let c = (((a.transpose() * b).trace() - 1.0) / 2.0).clamp(-1.0, 1.0);
    c.acos().to_degrees()
}

/// The per-row rotations of one eye for rectification: node b at row `b (rows - 1) / bands`.
#[derive(Debug, Clone, Copy)]
pub struct RowRotations<'a> {
    /// `R_b^T R_frame` per node (bands + 1 of them).
    pub nodes: &'a [Matrix3<f64>],
    /// Raw image height (px).
    pub rows: u32,
}

impl RowRotations<'_> {
    /// The rotation at raw row `y` (fractional; clamped to the image), linear between nodes: nodes are a
    /// few milliseconds apart, where a pursuit's rotation is linear in time to well under 0.01 deg.
    #[inline]
    pub fn at_row(&self, y: f64) -> Matrix3<f64> {
        let bands = self.nodes.len() - 1;
        if bands == 0 {
            return self.nodes[0];
        }
        let g = (y / (self.rows.max(2) - 1) as f64 * bands as f64).clamp(0.0, bands as f64);
        let i = (g as usize).min(bands - 1);
        let f = g - i as f64;
        self.nodes[i] * (1.0 - f) + self.nodes[i + 1] * f
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use abvs_eye::Fick;

    #[test]
    fn node_times_span_the_readout_around_the_frame_instant() {
        // 8 bands over 30 ms: first node 15 ms before the instant, last 15 ms after, middle at it
        assert_eq!(node_time_ns(1_000_000_000, 30_000_000, 0, 8), 985_000_000);
        assert_eq!(node_time_ns(1_000_000_000, 30_000_000, 4, 8), 1_000_000_000);
        assert_eq!(node_time_ns(1_000_000_000, 30_000_000, 8, 8), 1_015_000_000);
        let cfg = MotionConfig::default();
        assert_eq!(cfg.bands_for(0), 0);
        assert_eq!(cfg.bands_for(30_000_000), 8);
        assert_eq!(MotionConfig { rolling_shutter: false, ..cfg }.bands_for(30_000_000), 0);
    }

    #[test]
    fn row_rotation_interpolates_between_nodes() {
        let n: Vec<Matrix3<f64>> = (0..3).map(|k| Fick::from_deg([0.0, 0.0, k as f64]).to_matrix()).collect();
        let r = RowRotations { nodes: &n, rows: 101 };
        assert!((r.at_row(0.0) - n[0]).abs().max() < 1e-15);
        assert!((r.at_row(100.0) - n[2]).abs().max() < 1e-15);
        // a quarter down: half way between the first two nodes (0 and 1 deg of yaw) turns a ray by 0.5 deg
        let z = nalgebra::Vector3::z();
        assert!(((r.at_row(25.0) * z).angle(&z).to_degrees() - 0.5).abs() < 1e-4);
        assert!((r.at_row(-5.0) - n[0]).abs().max() < 1e-15);
    }
}
