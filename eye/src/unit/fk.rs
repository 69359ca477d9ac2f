//! The unit's true forward kinematics, compiled from a [`UnitModel`] ([`UnitFk`]), with the
//! per-sample conditions and the per-stream motion history it depends on.
use super::*;

/// Conditions of one sample beyond the readings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Conditions {
    /// Direction each link last moved (+1 / -1).
    pub dir: [f64; 3],
    /// Gravity in B (unit vector).
    pub gravity: [f64; 3],
    /// Direction (unit rotation axis in B) of the platform's last motion; homing ends with a
    /// positive roll, so +z before any other motion.
    pub platform_dir: [f64; 3],
}

impl Default for Conditions {
    fn default() -> Self {
        Conditions { dir: [1.0; 3], gravity: [0.0, 1.0, 0.0], platform_dir: [0.0, 0.0, 1.0] }
    }
}

/// Smallest platform rotation between samples (rad) that counts as a motion for the platform
/// lag: well below one encoder count's effect, well above Newton's round-off.
const PLATFORM_MOTION_RAD: f64 = 1e-6;

/// Tracks the direction each link last moved, from readings in acquisition order. A link that
/// did not move keeps its previous direction; before any motion it is + (homing ends moving +).
#[derive(Debug, Clone, Default)]
pub struct MotionHistory {
    last: Option<[f64; 3]>,
    dir: [f64; 3],
}

impl MotionHistory {
    pub fn new() -> Self {
        MotionHistory { last: None, dir: [1.0; 3] }
    }
    /// Feeds the next reading (deg) and returns the direction state for it.
    pub fn update(&mut self, reading_deg: &[f64; 3]) -> [f64; 3] {
        let half_count = 0.5 * 360.0 / COUNTS_PER_REV as f64;
        if let Some(last) = self.last {
            for i in 0..3 {
                let d = reading_deg[i] - last[i];
                if d.abs() > half_count {
                    self.dir[i] = d.signum();
                }
            }
        }
        self.last = Some(*reading_deg);
        self.dir
    }
}

/// The compiled true FK of a unit (see the module doc for the map).
#[derive(Debug, Clone)]
pub struct UnitFk {
    pub model: UnitModel,
    pub geom: SpmGeometry,
    mount: Pose,
    home_inv: Pose,
    home_r: Matrix3<f64>,
    /// Per head: the reading error's sin and (cos - 1) coefficients (rad).
    ecc: [(f64, f64); 3],
}

impl UnitFk {
    pub fn new(model: &UnitModel) -> Result<Self> {
        model.validate().map_err(|e| EyeError::Invalid(e.0))?;
        let e = &model.effects;
        let g = &model.geometry;
        let mut legs = [LegParams::nominal(0), LegParams::nominal(1), LegParams::nominal(2)];
        for (i, l) in legs.iter_mut().enumerate() {
            l.psi_deg = g.psi_deg[i];
            l.d1_deg = g.d1_deg;
            l.d2_deg = g.d2_deg;
            if e.link_angle_error.enabled {
                l.d1_deg += e.link_angle_error.d1_error_deg[i];
                l.d2_deg += e.link_angle_error.d2_error_deg[i];
            }
            if e.input_axis_tilt.enabled {
                l.axis_tilt_deg = [e.input_axis_tilt.tilt_x_deg[i], e.input_axis_tilt.tilt_y_deg[i]];
            }
            if e.platform_axis_error.enabled {
                l.platform_axis_deg = [e.platform_axis_error.azimuth_deg[i], e.platform_axis_error.elevation_deg[i]];
            }
        }
        let geom = SpmGeometry::from_params(&legs);
        let mount = if e.camera_mount.enabled {
            let m = &e.camera_mount;
            Pose::new(Fick::from_deg(m.rotation_deg).to_matrix(), Vector3::from(m.offset_mm))
        } else {
            Pose::identity()
        };
        let c = &e.code_wheel_eccentricity;
        let ecc = if c.enabled {
            let h = c.per_head_um();
            std::array::from_fn(|i| (h[i][0] * 1e-3 / c.wheel_radius_mm, h[i][1] * 1e-3 / c.wheel_radius_mm))
        } else {
            [(0.0, 0.0); 3]
        };
        let mut fk =
            UnitFk { model: model.clone(), geom, mount, home_inv: Pose::identity(), home_r: Matrix3::identity(), ecc };
        let (home_c, home_r) = fk.camera_in_base(&[0.0; 3], &Conditions::default(), None)?;
        fk.home_inv = home_c.inverse();
        fk.home_r = home_r;
        Ok(fk)
    }

    /// Platform orientation at home (for warm starts).
    pub fn home_platform(&self) -> Matrix3<f64> {
        self.home_r
    }

    /// True link angles (rad) for readings (deg) and directions (step 1-2 of the module doc).
    pub fn link_angles(&self, reading_deg: &[f64; 3], dir: &[f64; 3]) -> [f64; 3] {
        let e = &self.model.effects;
        let mut th = [0.0; 3];
        for i in 0..3 {
            let q = reading_deg[i].to_radians();
            let mut t = q;
            if e.encoder_scale.enabled {
                t *= 1.0 + e.encoder_scale.relative_error[i];
            }
            if e.encoder_zero_offset.enabled {
                t += e.encoder_zero_offset.offset_deg[i].to_radians();
            }
            let (ex, ey) = self.ecc[i];
            if ex != 0.0 || ey != 0.0 {
                t -= ex * q.sin() + ey * (q.cos() - 1.0);
            }
            if e.hinge_backlash.enabled {
                t -= dir[i] * 0.5 * e.hinge_backlash.backlash_deg[i].to_radians();
            }
            th[i] = t;
        }
        th
    }

    /// Camera pose in B and the platform orientation (for warm starts).
    fn camera_in_base(
        &self,
        reading_deg: &[f64; 3],
        cond: &Conditions,
        warm: Option<&Matrix3<f64>>,
    ) -> Result<(Pose, Matrix3<f64>)> {
        let r = self.platform(reading_deg, &cond.dir, warm, true)?;
        Ok((self.camera_from_platform(&r, cond), r))
    }

    /// Platform orientation of the mechanism (steps 1-3 of the module doc), before the platform
    /// lag and the sag: the state the next sample warm-starts from.
    fn platform(
        &self,
        reading_deg: &[f64; 3],
        dir: &[f64; 3],
        warm: Option<&Matrix3<f64>>,
        check: bool,
    ) -> Result<Matrix3<f64>> {
        let th = self.link_angles(reading_deg, dir);
        let sol = match warm {
            Some(r0) => self.geom.fk_from(&th, r0).or_else(|_| self.geom.fk_cold(&th))?,
            None => self.geom.fk_cold(&th)?,
        };
        if check {
            self.geom.check_regular(&sol.r, &th)?;
        }
        Ok(sol.r)
    }

    /// Camera pose in B from the mechanism's platform orientation: platform lag, hinge lag, sag,
    /// mount.
    fn camera_from_platform(&self, r: &Matrix3<f64>, cond: &Conditions) -> Pose {
        let mut rp = *r;
        let lag = self.model.effects.hinge_backlash.platform_lag_deg;
        if self.model.effects.hinge_backlash.enabled && lag != 0.0 {
            rp = exp_so3(&(Vector3::from(cond.platform_dir) * -lag.to_radians())) * rp;
        }
        let hb = &self.model.effects.hinge_backlash;
        if hb.enabled && hb.hinge_lag_deg.iter().any(|h| *h != 0.0) {
            // Each leg's clearance at its platform hinge: a turn about that hinge's axis, on the
            // side link i last pushed from (summed: each is a few hundredths of a degree).
            let w: Vector3<f64> = (0..3)
                .map(|i| rp * self.geom.legs[i].v0 * (-0.5 * cond.dir[i] * hb.hinge_lag_deg[i].to_radians()))
                .sum();
            rp = exp_so3(&w) * rp;
        }
        let sag = &self.model.effects.gravity_sag;
        if sag.enabled {
            let a = Vector3::from(sag.sag_deg).map(f64::to_radians);
            let d = (rp * a).cross(&Vector3::from(cond.gravity));
            rp = exp_so3(&d) * rp;
        }
        Pose::new(rp, Vector3::zeros()).compose(&self.mount)
    }

    /// Camera pose relative to home for readings (deg). Returns the pose and the platform
    /// orientation to warm-start the next call with.
    pub fn pose(
        &self,
        reading_deg: &[f64; 3],
        cond: &Conditions,
        warm: Option<&Matrix3<f64>>,
    ) -> Result<(Pose, Matrix3<f64>)> {
        let (c, r) = self.camera_in_base(reading_deg, cond, warm)?;
        Ok((self.home_inv.compose(&c), r))
    }

    /// As [`UnitFk::pose`] without the singularity check (still the working mode): for a
    /// solver's intermediate candidates; its answer is checked with [`UnitFk::pose`] or
    /// [`UnitFk::next`].
    pub fn pose_unchecked(
        &self,
        reading_deg: &[f64; 3],
        cond: &Conditions,
        warm: Option<&Matrix3<f64>>,
    ) -> Result<(Pose, Matrix3<f64>)> {
        let r = self.platform(reading_deg, &cond.dir, warm, false)?;
        Ok((self.home_inv.compose(&self.camera_from_platform(&r, cond)), r))
    }

    /// `P = [alpha, beta, gamma (deg), x, y, z (mm)]` for one reading.
    pub fn p6(&self, reading_deg: &[f64; 3], cond: &Conditions) -> Result<[f64; 6]> {
        Ok(self.pose(reading_deg, cond, Some(&self.home_r))?.0.to_p6())
    }

    /// A new stream of readings in acquisition order (one per eye): see [`UnitFk::next`].
    pub fn stream(&self) -> UnitStream {
        UnitStream { hist: MotionHistory::new(), warm: self.home_r, platform_dir: [0.0, 0.0, 1.0] }
    }

    /// The next reading of a stream -> camera pose relative to home. The reading updates the
    /// motion history (backlash direction) even if the pose fails, as the links did move; the
    /// warm start advances only on success.
    pub fn next(&self, st: &mut UnitStream, reading_deg: &[f64; 3], gravity: [f64; 3]) -> Result<Pose> {
        let warm = st.warm;
        self.next_from(st, reading_deg, gravity, &warm)
    }

    /// As [`UnitFk::next`], with the mechanism's Newton started from `start` (a platform
    /// orientation near the answer) instead of the stream's last one; same result, fewer
    /// iterations after a large move.
    pub fn next_from(
        &self,
        st: &mut UnitStream,
        reading_deg: &[f64; 3],
        gravity: [f64; 3],
        start: &Matrix3<f64>,
    ) -> Result<Pose> {
        let dir = st.hist.update(reading_deg);
        let (cond, r) = self.step(st, reading_deg, dir, gravity, start, true)?;
        st.platform_dir = cond.platform_dir;
        st.warm = r;
        Ok(self.home_inv.compose(&self.camera_from_platform(&r, &cond)))
    }

    /// The conditions (link directions, platform motion direction, gravity) and the platform
    /// orientation that [`UnitFk::next`] would give the reading, without advancing the stream:
    /// for solvers that try candidate readings (calibrated IK) and then evaluate them with
    /// [`UnitFk::pose_unchecked`] under these conditions. `start`: where the mechanism's Newton
    /// starts (a platform orientation near the answer; default the stream's last one). Like
    /// `pose_unchecked`, it checks the working mode but not the singularity margin.
    pub fn peek(
        &self,
        st: &UnitStream,
        reading_deg: &[f64; 3],
        gravity: [f64; 3],
        start: Option<&Matrix3<f64>>,
    ) -> Result<(Conditions, Matrix3<f64>)> {
        let dir = st.hist.clone().update(reading_deg);
        self.step(st, reading_deg, dir, gravity, start.unwrap_or(&st.warm), false)
    }

    /// Platform orientation and conditions of the stream's next reading (shared by next and peek).
    fn step(
        &self,
        st: &UnitStream,
        reading_deg: &[f64; 3],
        dir: [f64; 3],
        gravity: [f64; 3],
        start: &Matrix3<f64>,
        check: bool,
    ) -> Result<(Conditions, Matrix3<f64>)> {
        let r = self.platform(reading_deg, &dir, Some(start), check)?;
        let w = crate::pose::rotation_vector(&(r * st.warm.transpose()));
        let platform_dir = if w.norm() > PLATFORM_MOTION_RAD { (w / w.norm()).into() } else { st.platform_dir };
        Ok((Conditions { dir, gravity, platform_dir }, r))
    }

    /// Predicted poses for a dataset, walking it in acquisition order so motion history
    /// (backlash) and per-sample gravity are applied as recorded. Errors name the sample.
    pub fn predict_dataset(&self, data: &crate::dataset::Dataset) -> Result<Vec<[f64; 6]>> {
        let mut st = self.stream();
        data.samples
            .iter()
            .map(|s| {
                self.next(&mut st, &s.theta_deg, s.gravity_or_default())
                    .map(|p| p.to_p6())
                    .map_err(|e| EyeError::Invalid(format!("sample seq {}: {e}", s.seq)))
            })
            .collect()
    }
}

/// Per-stream state of a unit's true FK: the motion history and the previous platform
/// orientation (warm start).
#[derive(Debug, Clone)]
pub struct UnitStream {
    hist: MotionHistory,
    warm: Matrix3<f64>,
    platform_dir: [f64; 3],
}
