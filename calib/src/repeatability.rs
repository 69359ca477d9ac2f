//! Pose repeatability after ISO 9283 from repeated approaches to commanded targets, in the layout
//! of the paper's Table I (its C0: 0.019 deg per axis worst, 0.022 deg overall, encoder readings
//! within +-0.01 deg).
//!
//! # Input
//! A dataset (dataset.md) whose rows are measurements at the targets, in acquisition order, with
//! the commanded pose (cmd_alpha_deg, cmd_beta_deg, cmd_gamma_deg: rows with the same command
//! belong to one target). Approaches: the `approach` column when present (with `target`, as
//! `abvs sim repeatability` writes); otherwise a new approach starts whenever the command or the
//! link readings change. Several rows of one approach (the links standing still) are repeated
//! measurements of one pose.
//!
//! # Statistics, per target (n approaches, m measurements each)
//! Each approach's pose is the mean of its measurements; the barycentre is the mean of those.
//! - Orientation, per Fick angle a (alpha, beta, gamma): `RP_a = +-3 S_a`,
//!   `S_a^2 = sum_j (a_j - a_mean)^2 / (n - 1)` (ISO 9283 7.2.2).
//! - Overall rotation (the paper's "overall"): `RP_r = w_mean + 3 S_w`, `w_j` the angle between
//!   approach j's orientation and the mean orientation (the analogue of RP_l).
//! - Position: `RP_l = l_mean + 3 S_l`, `l_j = |p_j - p_mean|` (mm, optical centre).
//! - Encoder readings: the largest |reading - its mean| over links and approaches (+-deg).
//! - Accuracy (ISO 9283 AP, the paper's "ideal vs measured"): the angle between the mean
//!   orientation and the commanded one.
//!
//! # Measurement noise
//! Every measurement carries the measuring system's noise, which inflates the scatter. With m > 1
//! measurements per approach, the scatter within approaches is noise alone (the links do not
//! move): its pooled variance s_w^2 estimates it, and the approach means carry s_w^2 / m of it.
//! That share is removed: `S_a^2 = s_b^2 - s_w^2 / m`, and for the distances
//! `l_j^2 <- l_j^2 - 3 (n - 1) / n * s_w^2 / m` (likewise w_j); negative values become 0. The
//! share of the measured variance that was noise is reported; above one half, the value is
//! limited by the measurement (marked `*` in the table): ISO 9283 asks for a measuring system
//! well below the repeatability measured. With one measurement per approach nothing is removed.
use crate::error::{CalibError, Result};
use abvs_eye::dataset::Dataset;
use abvs_eye::pose::{rotation_vector, Fick};
use nalgebra::{Matrix3, Vector3};
use serde::Serialize;

/// A noise share above this marks a value as limited by the measurement.
pub const NOISE_LIMITED: f64 = 0.5;

/// One repeatability figure with the share of its measured variance that was noise.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Figure {
    /// The repeatability (deg or mm), measurement noise removed.
    pub value: f64,
    /// The same without removing the noise (ISO 9283 on the approach means as measured).
    pub raw: f64,
    /// Fraction of the measured variance attributed to measurement noise.
    pub noise_share: f64,
}

impl Figure {
    pub fn limited(&self) -> bool {
        self.noise_share > NOISE_LIMITED
    }
}

/// Repeatability at one target.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TargetRepeatability {
    /// Commanded orientation (Fick, deg).
    pub cmd_deg: [f64; 3],
    pub approaches: usize,
    /// Measurements per approach (the smallest, if they differ).
    pub images: usize,
    /// Barycentre of the approaches: [alpha, beta, gamma (deg), x, y, z (mm)].
    pub mean_pose: [f64; 6],
    /// RP_alpha, RP_beta, RP_gamma (+-deg).
    pub axes: [Figure; 3],
    /// RP_r: overall rotational repeatability (deg).
    pub rotation: Figure,
    /// RP_l: position repeatability of the optical centre (mm).
    pub position: Figure,
    /// Largest |encoder reading - its mean| over links and approaches (+-deg).
    pub encoder_deg: f64,
    /// Angle between the mean and the commanded orientation (deg): pose accuracy.
    pub accuracy_deg: f64,
    /// Estimated measurement noise per image (1-sigma, per axis): rotation (deg), translation (mm).
    pub noise_rot_deg: f64,
    pub noise_trans_mm: f64,
}

struct Approach {
    reading: [f64; 3],
    poses: Vec<[f64; 6]>,
}

fn column(data: &Dataset, name: &str) -> Option<usize> {
    data.extra_columns.iter().position(|c| c == name)
}

/// Groups rows into targets (by command, in order of first appearance) and approaches.
fn group(data: &Dataset) -> Result<Vec<([f64; 3], Vec<Approach>)>> {
    if !data.has_cmd() {
        return Err(CalibError::Data(
            "repeatability needs the commanded pose of every row (cmd_alpha_deg, cmd_beta_deg, cmd_gamma_deg)".into(),
        ));
    }
    let ac = column(data, "approach");
    let mut targets: Vec<([f64; 3], Vec<Approach>)> = vec![];
    let mut prev: Option<(usize, String, [f64; 3])> = None;
    for s in &data.samples {
        let cmd = s.cmd_deg.ok_or_else(|| CalibError::Data(format!("sample seq {}: no commanded pose", s.seq)))?;
        let ti = match targets.iter().position(|(c, _)| *c == cmd) {
            Some(i) => i,
            None => {
                targets.push((cmd, vec![]));
                targets.len() - 1
            }
        };
        let tag = ac.map(|c| s.extra[c].clone()).unwrap_or_default();
        let same =
            matches!(&prev, Some((pt, ptag, pr)) if *pt == ti && *ptag == tag && (ac.is_some() || *pr == s.theta_deg));
        if !same {
            targets[ti].1.push(Approach { reading: s.theta_deg, poses: vec![] });
        }
        targets[ti].1.last_mut().expect("an approach").poses.push(s.pose);
        prev = Some((ti, tag, s.theta_deg));
    }
    Ok(targets)
}

fn mean_of<const N: usize>(v: &[[f64; N]]) -> [f64; N] {
    let mut m = [0.0; N];
    for x in v {
        for k in 0..N {
            m[k] += x[k];
        }
    }
    m.map(|s| s / v.len() as f64)
}

/// Mean rotation of a set (chordal mean: the sum projected back onto SO(3)).
fn mean_rotation(rs: &[Matrix3<f64>]) -> Matrix3<f64> {
    let sum: Matrix3<f64> = rs.iter().sum();
    let svd = sum.svd(true, true);
    let (u, vt) = (svd.u.expect("u"), svd.v_t.expect("v_t"));
    let mut d = Matrix3::identity();
    if (u * vt).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    u * d * vt
}

fn sample_var(v: &[f64]) -> f64 {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0)
}

/// `l_mean + 3 S_l` of distances whose squares carry `noise_sq` of noise (removed).
fn distance_figure(l: &[f64], noise_sq: f64) -> Figure {
    let stat = |v: &[f64]| {
        let n = v.len() as f64;
        let m = v.iter().sum::<f64>() / n;
        m + 3.0 * sample_var(v).sqrt()
    };
    let measured_ms = l.iter().map(|x| x * x).sum::<f64>() / l.len() as f64;
    let corrected: Vec<f64> = l.iter().map(|x| (x * x - noise_sq).max(0.0).sqrt()).collect();
    let share = if measured_ms > 0.0 { (noise_sq / measured_ms).min(1.0) } else { 0.0 };
    Figure { value: stat(&corrected), raw: stat(l), noise_share: share }
}

/// ISO 9283 repeatability per target; see the module doc.
pub fn repeatability(data: &Dataset) -> Result<Vec<TargetRepeatability>> {
    let groups = group(data)?;
    let mut out = vec![];
    for (cmd, apps) in groups {
        let n = apps.len();
        if n < 2 {
            return Err(CalibError::Data(format!(
                "target {cmd:?} deg has {n} approach; repeatability needs at least 2"
            )));
        }
        let m = apps.iter().map(|a| a.poses.len()).min().expect("approaches");
        // Approach means: Fick angles and positions averaged; rotations by the chordal mean.
        let rots: Vec<Vec<Matrix3<f64>>> = apps
            .iter()
            .map(|a| a.poses.iter().map(|p| Fick::from_deg([p[0], p[1], p[2]]).to_matrix()).collect())
            .collect();
        let r_app: Vec<Matrix3<f64>> = rots.iter().map(|r| mean_rotation(r)).collect();
        let p_app: Vec<[f64; 6]> = apps.iter().map(|a| mean_of(&a.poses)).collect();
        let r_bar = mean_rotation(&r_app);
        let p_bar = mean_of(&p_app);
        // Within-approach (noise) variances, pooled over approaches: per Fick angle, per
        // rotation-vector component (deg^2) and per position axis (mm^2).
        let (mut ss_a, mut ss_r, mut ss_p, mut df) = ([0.0; 3], 0.0, 0.0, 0usize);
        for (j, a) in apps.iter().enumerate() {
            for (k, p) in a.poses.iter().enumerate() {
                for i in 0..3 {
                    ss_a[i] += (p[i] - p_app[j][i]).powi(2);
                    ss_p += (p[3 + i] - p_app[j][3 + i]).powi(2);
                }
                ss_r += rotation_vector(&(r_app[j].transpose() * rots[j][k])).map(f64::to_degrees).norm_squared();
            }
            df += a.poses.len() - 1;
        }
        let per_image = |ss: f64, comps: f64| if df > 0 { ss / (df as f64 * comps) } else { 0.0 };
        let mf = m as f64;
        let axes: [Figure; 3] = std::array::from_fn(|i| {
            let v: Vec<f64> = p_app.iter().map(|p| p[i]).collect();
            let (sb, noise) = (sample_var(&v), per_image(ss_a[i], 1.0) / mf);
            Figure {
                value: 3.0 * (sb - noise).max(0.0).sqrt(),
                raw: 3.0 * sb.sqrt(),
                noise_share: if sb > 0.0 { (noise / sb).min(1.0) } else { 0.0 },
            }
        });
        let scale = 3.0 * (n as f64 - 1.0) / n as f64 / mf;
        let w: Vec<f64> = r_app.iter().map(|r| rotation_vector(&(r_bar.transpose() * r)).norm().to_degrees()).collect();
        let rotation = distance_figure(&w, scale * per_image(ss_r, 3.0));
        let l: Vec<f64> =
            p_app.iter().map(|p| Vector3::new(p[3] - p_bar[3], p[4] - p_bar[4], p[5] - p_bar[5]).norm()).collect();
        let position = distance_figure(&l, scale * per_image(ss_p, 3.0));
        let readings: Vec<[f64; 3]> = apps.iter().map(|a| a.reading).collect();
        let rm = mean_of(&readings);
        let encoder_deg = readings.iter().flat_map(|r| (0..3).map(move |i| (r[i] - rm[i]).abs())).fold(0.0, f64::max);
        let fb = Fick::from_matrix(&r_bar).to_deg();
        let r_cmd = Fick::from_deg(cmd).to_matrix();
        out.push(TargetRepeatability {
            cmd_deg: cmd,
            approaches: n,
            images: m,
            mean_pose: [fb[0], fb[1], fb[2], p_bar[3], p_bar[4], p_bar[5]],
            axes,
            rotation,
            position,
            encoder_deg,
            accuracy_deg: rotation_vector(&(r_cmd.transpose() * r_bar)).norm().to_degrees(),
            noise_rot_deg: per_image(ss_r, 3.0).sqrt(),
            noise_trans_mm: per_image(ss_p, 3.0).sqrt(),
        });
    }
    Ok(out)
}

fn fig(f: &Figure, digits: usize) -> String {
    format!("{:.*}{}", digits, f.value, if f.limited() { "*" } else { "" })
}

/// The paper's Table I layout (markdown): one row per target and the worst over all targets.
pub fn table(rows: &[TargetRepeatability]) -> String {
    let mut s = String::from(
        "| target | commanded alpha, beta, gamma (deg) | measured (mean) alpha, beta, gamma (deg) | approaches x images \
         | RP_alpha (+-deg) | RP_beta (+-deg) | RP_gamma (+-deg) | RP_rot (deg) | RP_l (mm) | encoder readings (+-deg) \
         | noise per image rot (deg) / trans (mm) |\n| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n",
    );
    for (k, r) in rows.iter().enumerate() {
        let (c, p) = (r.cmd_deg, r.mean_pose);
        s += &format!(
            "| P{} | {:.3}, {:.3}, {:.3} | {:.3}, {:.3}, {:.3} | {} x {} | {} | {} | {} | {} | {} | {:.4} | {:.4} / {:.4} |\n",
            k + 1,
            c[0],
            c[1],
            c[2],
            p[0],
            p[1],
            p[2],
            r.approaches,
            r.images,
            fig(&r.axes[0], 4),
            fig(&r.axes[1], 4),
            fig(&r.axes[2], 4),
            fig(&r.rotation, 4),
            fig(&r.position, 4),
            r.encoder_deg,
            r.noise_rot_deg,
            r.noise_trans_mm
        );
    }
    let worst = |f: &dyn Fn(&TargetRepeatability) -> f64| rows.iter().map(f).fold(0.0, f64::max);
    s += &format!(
        "| worst | | | | {:.4} | {:.4} | {:.4} | {:.4} | {:.4} | {:.4} | |\n",
        worst(&|r| r.axes[0].value),
        worst(&|r| r.axes[1].value),
        worst(&|r| r.axes[2].value),
        worst(&|r| r.rotation.value),
        worst(&|r| r.position.value),
        worst(&|r| r.encoder_deg)
    );
    if rows.iter().any(|r| r.axes.iter().chain([&r.rotation, &r.position]).any(Figure::limited)) {
        s += &format!(
            "\n`*`: more than {:.0}% of the measured variance was measurement noise (removed): the value is limited \
             by the measuring system; take more images per approach or a finer measurement.\n",
            NOISE_LIMITED * 100.0
        );
    }
    s
}
