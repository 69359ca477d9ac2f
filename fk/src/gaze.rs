//! Binocular fixation: the link angles of both eyes that put a 3D point on each camera's
//! principal point, from both eyes' calibrated FK models ([`crate::ik`]) and the stereo
//! extrinsic at home T_lH^rH (conventions.md, Two eyes).
//!
//! # What "on the principal point" means
//! The principal point is the image of the optical axis (the camera frame's +z): in every lens
//! model of abvs-camera (pinhole, rational, fisheye) distortion is radial about it. So an eye
//! fixates a point X when its camera's optical axis passes through X: with the camera pose
//! relative to home `(R, t)` (t: the optical centre, mm, in the home camera frame),
//! `R e_z = (X - t) / |X - t|`, X in front of the camera.
//!
//! # Torsion
//! A gaze direction fixes two of the three rotational degrees of freedom; the third (torsion
//! about the optical axis) is chosen by a rule ([`Torsion`]):
//! - [`Torsion::Listing`] (default), Listing's law: every gaze direction is reached from the
//!   primary position (home, looking along +z) by a single rotation about an axis in Listing's
//!   plane (the home x-y plane), `R = exp(angle * (e_z x d) / |e_z x d|)`, as human eyes do.
//!   In Fick angles this has a small roll for oblique gaze, about `alpha * gamma / 2` (rad):
//!   3.6 deg at alpha = gamma = 20 deg, 8 deg at 30 / 30, inside the +-15 deg roll workspace.
//! - [`Torsion::ZeroFick`]: Fick roll beta = 0 (`R = Ry(gamma) Rx(alpha)`), like a gimbal.
//!
//! # Translation follows
//! The optical centre moves with the orientation (the camera sits a few mm in front of the
//! spherical centre), and that shifts the direction to a near target by up to a few degrees.
//! Each eye therefore iterates: aim from the model's predicted optical centre, solve the
//! calibrated IK, take the new predicted centre, until it moves less than 1e-6 mm (a fixed
//! point; the correction contracts by about offset / distance per round).
//!
//! # Moves
//! [`YokedSaccade`]: both eyes' minimum-jerk link moves ([`abvs_eye::saccade::MinJerk`]) to a
//! fixation, at a peak link speed, yoked (the slower eye's duration for both, so both arrive
//! together), with the targets rounded to encoder counts as the drive board takes them.
//! [`Pursuit`]: a point moving at a constant velocity; smooth pursuit re-solves the fixation for the
//! point at each frame's time ([`Binocular::pursue_at`]), each solve reached from the last.
use crate::error::{FkError as CalibError, Result};
use crate::ik::{CalibratedIk, IkSolution};
use crate::model::FkState;
use abvs_eye::encoder::{counts_to_deg, deg_to_counts};
use abvs_eye::pose::{exp_so3, Fick, Pose};
use abvs_eye::saccade::MinJerk;
use nalgebra::Vector3;

/// How torsion about the line of sight is chosen; see the module doc.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Torsion {
    /// Listing's law.
    #[default]
    Listing,
    /// Fick roll 0.
    #[cfg_attr(feature = "clap", value(alias = "zero"))]
    ZeroFick,
}

impl Torsion {
    pub fn parse(s: &str) -> Result<Torsion> {
        match s {
            "listing" => Ok(Torsion::Listing),
            "zero-fick" | "zero" => Ok(Torsion::ZeroFick),
            _ => Err(CalibError::Invalid(format!("unknown torsion rule '{s}' (listing, zero-fick)"))),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Torsion::Listing => "listing",
            Torsion::ZeroFick => "zero-fick",
        }
    }

    /// Fick angles (deg) of the orientation that looks along `d` (unit, home camera frame).
    pub fn orientation_deg(self, d: &Vector3<f64>) -> [f64; 3] {
        let d = d.normalize();
        match self {
            Torsion::Listing => {
                let axis = Vector3::z().cross(&d);
                let s = axis.norm();
                let angle = s.atan2(d.z);
                let r = if s < 1e-15 { exp_so3(&Vector3::zeros()) } else { exp_so3(&(axis * (angle / s))) };
                Fick::from_matrix(&r).to_deg()
            }
            Torsion::ZeroFick => {
                // Ry(g) Rx(a) e_z = [cos a sin g, -sin a, cos a cos g].
                let alpha = (-d.y).clamp(-1.0, 1.0).asin();
                let gamma = d.x.atan2(d.z);
                [alpha.to_degrees(), 0.0, gamma.to_degrees()]
            }
        }
    }
}

/// One eye's part of a fixation.
#[derive(Debug, Clone, PartialEq)]
pub struct EyeAim {
    /// The calibrated IK's answer (link angles, counts, predicted pose, residual).
    pub ik: IkSolution,
    /// The point in this eye's home camera frame (mm).
    pub point_mm: [f64; 3],
    /// Distance of the point from the predicted optical axis (mm): the IK residual and the
    /// fixed point's tolerance, so ~0.
    pub predicted_miss_mm: f64,
    /// Distance from the predicted optical centre to the point (mm).
    pub range_mm: f64,
    /// Fixed-point rounds (each a calibrated IK solve).
    pub rounds: usize,
}

/// Both eyes fixating one point.
#[derive(Debug, Clone, PartialEq)]
pub struct Fixation {
    /// The point in the left home camera frame (mm).
    pub point_mm: [f64; 3],
    pub left: EyeAim,
    pub right: EyeAim,
    /// Angle between the two optical axes (deg), both in the left home camera frame.
    pub vergence_deg: f64,
    pub torsion: Torsion,
}

/// Points closer than this to an optical centre are refused (mm).
pub const MIN_RANGE_MM: f64 = 50.0;

/// Both eyes' calibrated IK and the stereo extrinsic at home.
pub struct Binocular<'m> {
    pub left: CalibratedIk<'m>,
    pub right: CalibratedIk<'m>,
    /// T_lH^rH: left home camera frame -> right home camera frame (x_r = R x_l + t, mm).
    pub left_to_right: Pose,
    pub torsion: Torsion,
}

/// Distance (mm) of `p` from the line through `o` along unit `d`.
pub fn distance_to_axis(p: &Vector3<f64>, o: &Vector3<f64>, d: &Vector3<f64>) -> f64 {
    let v = p - o;
    (v - d * v.dot(d)).norm()
}

/// Optical centre (mm) and axis direction of a pose `[alpha, beta, gamma, x, y, z]`.
pub fn optical_axis(pose: &[f64; 6]) -> (Vector3<f64>, Vector3<f64>) {
    let r = Fick::from_deg([pose[0], pose[1], pose[2]]).to_matrix();
    (Vector3::new(pose[3], pose[4], pose[5]), r * Vector3::z())
}

/// The point (mm, the eye's home camera frame) seen along `ray_cam` (a direction in the camera
/// frame, e.g. an unprojected pixel) at `depth_mm` (its z in the camera frame, the depth-map
/// convention), with the eye at link angles `theta_deg` as its calibrated model predicts it.
/// What a fixation "at this pixel of the current image" needs: the image was taken from the eye's
/// current pose, not from home.
pub fn point_from_view(
    model: &crate::model::FkModel,
    theta_deg: [f64; 3],
    gravity: [f64; 3],
    ray_cam: &Vector3<f64>,
    depth_mm: f64,
) -> Result<[f64; 3]> {
    if !(depth_mm.is_finite() && depth_mm > 0.0) {
        return Err(CalibError::Invalid(format!("depth {depth_mm} mm: must be finite and positive")));
    }
    if !(ray_cam.z > 1e-9) {
        return Err(CalibError::Invalid(format!("ray {:?} does not point in front of the camera", ray_cam.as_slice())));
    }
    let pose = model.eval(&mut model.state(), &theta_deg, gravity)?;
    let r = Fick::from_deg([pose[0], pose[1], pose[2]]).to_matrix();
    let x = r * (ray_cam * (depth_mm / ray_cam.z)) + Vector3::new(pose[3], pose[4], pose[5]);
    Ok([x.x, x.y, x.z])
}

impl<'m> Binocular<'m> {
    /// One eye aims at `p` (mm, its home frame) from state `st`; returns the aim and the state
    /// advanced by the move.
    pub fn aim(
        ik: &CalibratedIk,
        torsion: Torsion,
        st: &FkState,
        p: &Vector3<f64>,
        gravity: [f64; 3],
    ) -> Result<(EyeAim, FkState)> {
        let mut centre = Vector3::zeros();
        let refuse = |why: String| CalibError::Invalid(format!("point {:?} mm: {why}", [p.x, p.y, p.z]));
        for round in 1..=12 {
            let v = p - centre;
            if v.norm() < MIN_RANGE_MM {
                return Err(refuse(format!("{:.1} mm from the optical centre (at least {MIN_RANGE_MM} mm)", v.norm())));
            }
            if v.z <= 0.0 {
                return Err(refuse("behind the eye (z <= 0 in its home camera frame)".into()));
            }
            let target = torsion.orientation_deg(&v.normalize());
            let (sol, next) = ik.solve_with_next(st, target, gravity)?;
            let (c, d) = optical_axis(&sol.pose);
            let moved = (c - centre).norm();
            centre = c;
            if moved < 1e-6 || round == 12 {
                let aim = EyeAim {
                    point_mm: [p.x, p.y, p.z],
                    predicted_miss_mm: distance_to_axis(p, &c, &d),
                    range_mm: (p - c).norm(),
                    rounds: round,
                    ik: sol,
                };
                return Ok((aim, next));
            }
        }
        unreachable!("the loop returns at round 12")
    }

    /// Both eyes fixate `point_mm` (left home camera frame, mm) from the states `st` (moved on
    /// success only, both or neither).
    pub fn fixate_and_move(
        &self,
        st: [&mut FkState; 2],
        point_mm: [f64; 3],
        gravity: [[f64; 3]; 2],
    ) -> Result<Fixation> {
        let pl = Vector3::from(point_mm);
        let pr = self.left_to_right.r * pl + self.left_to_right.t;
        let (left, nl) = Self::aim(&self.left, self.torsion, st[0], &pl, gravity[0])
            .map_err(|e| CalibError::Invalid(format!("left eye: {e}")))?;
        let (right, nr) = Self::aim(&self.right, self.torsion, st[1], &pr, gravity[1])
            .map_err(|e| CalibError::Invalid(format!("right eye: {e}")))?;
        let dl = optical_axis(&left.ik.pose).1;
        let dr = self.left_to_right.r.transpose() * optical_axis(&right.ik.pose).1;
        let vergence_deg = dl.dot(&dr).clamp(-1.0, 1.0).acos().to_degrees();
        *st[0] = nl;
        *st[1] = nr;
        Ok(Fixation { point_mm, left, right, vergence_deg, torsion: self.torsion })
    }

    /// Both eyes fixate `point_mm` from home (the motion history of a fresh start).
    pub fn fixate_from_home(&self, point_mm: [f64; 3], gravity: [f64; 3]) -> Result<Fixation> {
        let (mut a, mut b) = (self.left.model().state(), self.right.model().state());
        self.fixate_and_move([&mut a, &mut b], point_mm, [gravity; 2])
    }
}

/// Both eyes' minimum-jerk moves to new link angles, yoked; see the module doc.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct YokedSaccade {
    /// Link angles at the start, per eye (deg, homed).
    pub from_deg: [[f64; 3]; 2],
    /// Link angles at the end, per eye (deg, homed): the targets rounded to whole counts.
    pub to_deg: [[f64; 3]; 2],
    /// The targets as homed encoder counts, per eye.
    pub target_counts: [[i64; 3]; 2],
    /// The move's duration (us, whole): the slower eye's at the peak speed.
    pub duration_us: u32,
}

impl YokedSaccade {
    /// Moves from `from_deg` to `to_deg` (per eye, deg, homed) whose fastest link peaks at
    /// `peak_deg_s`.
    pub fn plan(from_deg: [[f64; 3]; 2], to_deg: [[f64; 3]; 2], peak_deg_s: f64) -> YokedSaccade {
        let target_counts = to_deg.map(|th| th.map(|d| deg_to_counts(d, 0)));
        let to_deg = target_counts.map(|c| c.map(|x| counts_to_deg(x, 0)));
        let dur =
            (0..2).map(|e| MinJerk::with_peak_speed(from_deg[e], to_deg[e], peak_deg_s).duration_s).fold(0.0, f64::max);
        let duration_us = (dur * 1e6).ceil().min(u32::MAX as f64) as u32;
        YokedSaccade { from_deg, to_deg, target_counts, duration_us }
    }

    /// Each eye's move over the yoked duration.
    pub fn moves(&self) -> [MinJerk; 2] {
        [0, 1].map(|e| MinJerk { from: self.from_deg[e], to: self.to_deg[e], duration_s: self.duration_s() })
    }

    /// The duration (s).
    pub fn duration_s(&self) -> f64 {
        self.duration_us as f64 * 1e-6
    }

    /// The largest link travel over both eyes (deg).
    pub fn travel_deg(&self) -> f64 {
        (0..2).flat_map(|e| (0..3).map(move |i| (self.to_deg[e][i] - self.from_deg[e][i]).abs())).fold(0.0, f64::max)
    }
}

/// A point moving at a constant velocity (smooth pursuit); see the module doc.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pursuit {
    /// Where the point is at time 0 (mm, left home camera frame).
    pub point_mm: [f64; 3],
    /// Its velocity (mm/s, left home camera frame).
    pub velocity_mm_s: [f64; 3],
}

impl Pursuit {
    /// The point at `t_s` seconds.
    pub fn point_at(&self, t_s: f64) -> [f64; 3] {
        std::array::from_fn(|i| self.point_mm[i] + self.velocity_mm_s[i] * t_s)
    }
}

impl Binocular<'_> {
    /// Smooth pursuit: both eyes fixate the pursued point at `t_s`, reached from the states `st`
    /// (the previous frame's solve; moved on success only).
    pub fn pursue_at(
        &self,
        st: [&mut FkState; 2],
        pursuit: &Pursuit,
        t_s: f64,
        gravity: [[f64; 3]; 2],
    ) -> Result<Fixation> {
        self.fixate_and_move(st, pursuit.point_at(t_s), gravity)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn torsion_rules_look_along_the_direction() {
        for d in [Vector3::new(0.3, -0.2, 1.0), Vector3::new(-0.5, 0.4, 0.8), Vector3::z()] {
            let d = d.normalize();
            for rule in [Torsion::Listing, Torsion::ZeroFick] {
                let f = rule.orientation_deg(&d);
                let r = Fick::from_deg(f).to_matrix();
                assert!((r * Vector3::z() - d).norm() < 1e-12, "{rule:?} {f:?}");
                if rule == Torsion::ZeroFick {
                    assert_eq!(f[1], 0.0);
                }
            }
        }
        // Listing: no torsion along the cardinal directions, about alpha*gamma/2 obliquely.
        let f = Torsion::Listing.orientation_deg(&Vector3::new(0.0, -0.5, 1.0));
        assert!(f[1].abs() < 1e-12 && f[2].abs() < 1e-12, "{f:?}");
        let f = Torsion::Listing.orientation_deg(&Fick::from_deg([20.0, 0.0, 20.0]).to_matrix().column(2).into());
        let want = (20f64.to_radians() * 20f64.to_radians() / 2.0).to_degrees();
        assert!((f[1] - want).abs() < 0.5, "{f:?} vs {want}");
    }

    #[test]
    fn yoked_saccade_takes_the_slower_eye_and_whole_counts() {
        let s = YokedSaccade::plan([[0.0; 3]; 2], [[10.0, -4.0, 2.0], [20.0, 1.0, 0.0]], 1561.0);
        // the right eye travels 20 deg: T = 15/8 * 20 / 1561 s for both
        let want = 1.875 * s.to_deg[1][0] / 1561.0;
        assert!((s.duration_s() - want).abs() < 1.5e-6, "{} vs {want}", s.duration_s());
        for e in 0..2 {
            assert_eq!(s.to_deg[e], s.target_counts[e].map(|c| counts_to_deg(c, 0)));
            assert_eq!(s.moves()[e].at(s.duration_s()), s.to_deg[e]);
            assert!(s.moves()[e].peak_speed() <= 1561.0 + 1e-6);
        }
        assert!((s.travel_deg() - s.to_deg[1][0]).abs() < 1e-12);
        let p = Pursuit { point_mm: [0.0, 0.0, 1000.0], velocity_mm_s: [100.0, 0.0, -50.0] };
        assert_eq!(p.point_at(0.5), [50.0, 0.0, 975.0]);
    }
}
