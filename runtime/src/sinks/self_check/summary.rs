//! The run's self-check statistics (bounded memory over a long run) and the per-frame log.
use super::log_record::FrameRecord;
use super::*;
use abvs_runtime_core::params::SelfCheckConfig;

pub(super) const BIN_PX: f64 = 0.005;
/// Checked frames kept for the run's rotation estimate and match count (about 33 minutes at 5 a second).
pub const KEEP: usize = 10_000;
pub(super) const BINS: usize = 4000;

/// The run's self-check: everything the worker accumulated.
pub struct Summary {
    /// Frames checked.
    pub frames: u64,
    /// Checked frames whose matches did not support a rotation fit.
    pub frames_unfitted: u64,
    /// Frames the worker was too busy for.
    pub skipped: u64,
    /// Warnings given (the rotation error over its threshold).
    pub warnings: u64,
    /// Matches of the last [`KEEP`] checked frames.
    matches: std::collections::VecDeque<u32>,
    /// |vertical disparity| histogram of all matches (BIN_PX bins, the last one open).
    vertical: Vec<u64>,
    /// Rotation fits of the last [`KEEP`] checked frames (the run's estimate is theirs: memory stays bounded).
    fits: std::collections::VecDeque<(Vector3<f64>, Matrix3<f64>)>,
    /// Time the worker spent on each checked frame.
    pub check_time: Latency,
    /// CPU time of the worker thread on each checked frame (what the check costs the machine).
    pub check_cpu: Latency,
    /// The last `warn_frames` frames' rotation errors.
    recent: std::collections::VecDeque<Vector3<f64>>,
    warned: bool,
    pub(super) failed: u64,
}

impl Default for Summary {
    fn default() -> Self {
        Summary {
            frames: 0,
            frames_unfitted: 0,
            skipped: 0,
            warnings: 0,
            matches: ring(0),
            vertical: written(BINS, 0u64).into(),
            fits: ring((Vector3::zeros(), Matrix3::zeros())),
            check_time: Latency::default(),
            check_cpu: Latency::default(),
            recent: std::collections::VecDeque::new(),
            warned: false,
            failed: 0,
        }
    }
}

/// `n` copies of `x` in a buffer each page of which is written now: resident from the first frame, so neither
/// the histogram's bins nor the rings (which take half an hour to fill) read as growth in a soak (issue 42).
/// (`black_box`: the buffer escapes before it is written, so the write cannot become a zeroed allocation.)
fn written<T: Clone>(n: usize, x: T) -> std::collections::VecDeque<T> {
    let mut v = std::collections::VecDeque::with_capacity(n);
    std::hint::black_box(&mut v);
    v.resize(n, x);
    std::hint::black_box(&mut v);
    v
}

/// An empty ring with room for [`KEEP`] frames, resident from the start.
fn ring<T: Clone>(x: T) -> std::collections::VecDeque<T> {
    let mut v = written(KEEP, x);
    v.clear();
    v
}

impl Summary {
    pub(super) fn add(&mut self, c: &FrameCheck, ms: &[Match], cfg: &SelfCheckConfig) {
        self.frames += 1;
        if self.matches.len() == KEEP {
            self.matches.pop_front();
        }
        self.matches.push_back(c.matches as u32);
        for m in ms {
            let b = ((m.dy().abs() as f64 / BIN_PX) as usize).min(BINS - 1);
            self.vertical[b] += 1;
        }
        match &c.fit {
            Some(f) => {
                if self.fits.len() == KEEP {
                    self.fits.pop_front();
                }
                self.fits.push_back((f.omega, f.info));
                let n = cfg.warn_frames.max(1) as usize;
                if self.recent.len() == n {
                    self.recent.pop_front();
                }
                self.recent.push_back(f.omega);
                if self.recent.len() == n {
                    // component-wise median of the window: a persistent error, not one odd frame
                    let med = |k: usize| {
                        let mut v: Vec<f64> = self.recent.iter().map(|w| w[k]).collect();
                        v.sort_by(f64::total_cmp);
                        0.5 * (v[(n - 1) / 2] + v[n / 2])
                    };
                    let m = Vector3::new(med(0), med(1), med(2)).map(f64::to_degrees);
                    if m.norm() > cfg.threshold_deg {
                        if !self.warned {
                            self.warned = true;
                            self.warnings += 1;
                            log::warn!(
                                "self-check: stereo rotation error [{:.3}, {:.3}, {:.3}] deg (median of the \
                                 last {n} checked frames, up to frame {}; |vertical| p50 {:.2} px) exceeds {} deg: \
                                 the calibration may be off",
                                m.x,
                                m.y,
                                m.z,
                                c.seq,
                                c.vertical_p50,
                                cfg.threshold_deg
                            );
                        }
                    } else {
                        self.warned = false;
                    }
                }
            }
            None => self.frames_unfitted += 1,
        }
    }

    pub(super) fn vertical_quantile(&self, q: f64) -> f64 {
        let n: u64 = self.vertical.iter().sum();
        if n == 0 {
            return f64::NAN;
        }
        let want = ((n as f64 * q).ceil() as u64).max(1);
        let mut acc = 0;
        for (i, c) in self.vertical.iter().enumerate() {
            acc += c;
            if acc >= want {
                return (i as f64 + 0.5) * BIN_PX;
            }
        }
        f64::NAN
    }

    /// The run's rotation error (rad) and its covariance from the scatter between frames: the information-
    /// weighted mean of the frames' estimates, each frame also weighted by Huber on its distance to the mean
    /// (in units of the robust spread of those distances).
    pub fn rotation(&self) -> Option<(Vector3<f64>, Matrix3<f64>)> {
        if self.fits.is_empty() {
            return None;
        }
        let mut fw = vec![1.0; self.fits.len()];
        let mut mean = Vector3::zeros();
        let mut a_sum = Matrix3::zeros();
        for it in 0..20 {
            let mut a = Matrix3::zeros();
            let mut b = Vector3::zeros();
            for ((om, info), w) in self.fits.iter().zip(&fw) {
                a += info * *w;
                b += info * om * *w;
            }
            let next = a.try_inverse()? * b;
            a_sum = a;
            let mut d: Vec<f64> = self.fits.iter().map(|(om, _)| (om - next).norm()).collect();
            let dist = d.clone();
            d.sort_by(f64::total_cmp);
            let k = 2.0 * 1.4826 * d[d.len() / 2].max(1e-12);
            for (w, x) in fw.iter_mut().zip(&dist) {
                *w = if *x <= k { 1.0 } else { k / x };
            }
            let step = (next - mean).norm();
            mean = next;
            if it > 0 && step < 1e-12 {
                break;
            }
        }
        let n = self.fits.len() as f64;
        let ainv = a_sum.try_inverse()?;
        let mut meat = Matrix3::zeros();
        for ((om, info), w) in self.fits.iter().zip(&fw) {
            let g = info * (om - mean) * *w;
            meat += g * g.transpose();
        }
        let cov = ainv * meat * ainv * if n > 1.0 { n / (n - 1.0) } else { f64::INFINITY };
        Some((mean, cov))
    }

    /// The stats JSON's `self_check` object.
    pub fn json(&self) -> Value {
        let mut m: Vec<u32> = self.matches.iter().copied().collect();
        m.sort_unstable();
        let matches_p50 = if m.is_empty() { Value::Null } else { json!(m[(m.len() - 1) / 2]) };
        let num = |x: f64| if x.is_finite() { json!((x * 1e4).round() / 1e4) } else { Value::Null };
        let (rot, sigma, axes) = match self.rotation() {
            Some((om, cov)) => {
                let s = Vector3::new(cov[(0, 0)].sqrt(), cov[(1, 1)].sqrt(), cov[(2, 2)].sqrt()).map(f64::to_degrees);
                (
                    json!([num(om.x.to_degrees()), num(om.y.to_degrees()), num(om.z.to_degrees())]),
                    num(s.max()),
                    json!([num(s.x), num(s.y), num(s.z)]),
                )
            }
            None => (Value::Null, Value::Null, Value::Null),
        };
        json!({
            "frames": self.frames,
            "frames_skipped": self.skipped,
            "frames_unfitted": self.frames_unfitted,
            "frames_failed": self.failed,
            "matches_p50": matches_p50,
            "vertical_px": { "p50": num(self.vertical_quantile(0.5)), "p95": num(self.vertical_quantile(0.95)) },
            "rotation_error_deg": rot,
            "rotation_sigma_deg": sigma,
            "rotation_sigma_axes_deg": axes,
            "warnings": self.warnings,
            "check_ms": { "p50": num(self.check_time.ms(0.5)), "p99": num(self.check_time.ms(0.99)) },
            "check_cpu_ms": { "p50": num(self.check_cpu.ms(0.5)), "p99": num(self.check_cpu.ms(0.99)) },
        })
    }
}

/// One line for the table `abvs run` prints, from the stats' `self_check` object.
pub fn summary_line(v: &Value) -> String {
    let f = |x: &Value| x.as_f64().map(|x| format!("{x:.3}")).unwrap_or_else(|| "-".into());
    let r = |k: usize| f(&v["rotation_error_deg"][k]);
    format!(
        "self-check: {} frames ({} skipped), matches p50 {}, |vertical| p50 {} p95 {} px, rotation error [{}, {}, {}] \
         deg (sigma {} deg), warnings {}",
        v["frames"],
        v["frames_skipped"],
        v["matches_p50"],
        f(&v["vertical_px"]["p50"]),
        f(&v["vertical_px"]["p95"]),
        r(0),
        r(1),
        r(2),
        f(&v["rotation_sigma_deg"]),
        v["warnings"]
    )
}

/// The per-frame log's record of a checked frame ([`FrameRecord`]): `accel_*` is how much each camera's mean
/// angular velocity changed from the 15 ms before the instant to the 15 ms after; the offsets are NaN (empty)
/// without a [`TimingContext`].
pub(super) fn frame_record(c: &FrameCheck, job: &Job, timing: Option<&TimingContext>, run_id: u64) -> FrameRecord {
    let t = &c.theta;
    let (om, sg) = match &c.fit {
        Some(fit) => (fit.omega.map(f64::to_degrees), fit.sigma.map(f64::to_degrees)),
        None => (Vector3::repeat(f64::NAN), Vector3::repeat(f64::NAN)),
    };
    let offsets = timing.map_or([f64::NAN; 2], |t| t.time_offset_ms);
    let accel = job.omega_wide_rad_s.map(|[a, b]| (b - a).norm().to_degrees());
    FrameRecord {
        seq: c.seq,
        t_ns: c.t_frame_ns,
        l1_deg: t[0][0],
        l2_deg: t[0][1],
        l3_deg: t[0][2],
        r1_deg: t[1][0],
        r2_deg: t[1][1],
        r3_deg: t[1][2],
        matches: c.matches as u64,
        vertical_p50_px: c.vertical_p50,
        vertical_p95_px: c.vertical_p95,
        rot_x_deg: om.x,
        rot_y_deg: om.y,
        rot_z_deg: om.z,
        rot_sigma_x_deg: sg.x,
        rot_sigma_y_deg: sg.y,
        rot_sigma_z_deg: sg.z,
        speed_l_deg_s: job.speed_deg_s[0],
        speed_r_deg_s: job.speed_deg_s[1],
        accel_l_deg_s: accel[0],
        accel_r_deg_s: accel[1],
        readout_ms: job.readout_ms,
        exposure_ms: job.exposure_ms,
        readout_anchor: job.readout_anchor,
        offset_l_ms: offsets[0],
        offset_r_ms: offsets[1],
        row_bands: Some(job.band_rot[0].len().saturating_sub(1) as u64),
        run_id: Some(run_id),
    }
}
