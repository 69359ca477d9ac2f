//! Structure in a residual that no library effect describes: the measurement-noise floor (the
//! part no model can remove), link-angle ripples (a periodic error of one link's angle, fitted
//! together with the model), and the description of what is left.
use crate::error::Result;
use crate::identify::residuals;
use abvs_eye::dataset::Dataset;
use abvs_eye::unit::UnitModel;
use nalgebra::DVector;

/// Ripple orders scanned: 1 cycle per revolution is the code wheel's eccentricity (a library
/// effect); 2..12 cover polygonal hubs, magnet poles and interpolation errors.
pub const RIPPLE_CYCLES: std::ops::RangeInclusive<usize> = 2..=12;

/// Per-axis noise sigma (rot deg, trans mm) from the high-frequency part of the residual:
/// second differences along runs of consecutive, evenly spaced samples cancel the smooth
/// systematic part; a robust (MAD) scale resists the odd jump (e.g. a backlash reversal).
/// Returns None where fewer than 90 such triples exist.
pub fn noise_from_second_differences(data: &Dataset, res: &[[f64; 6]]) -> Option<(f64, f64, usize)> {
    let s = &data.samples;
    let mut d2: [Vec<f64>; 2] = [vec![], vec![]];
    for i in 1..s.len().saturating_sub(1) {
        let (a, b, c) = (&s[i - 1], &s[i], &s[i + 1]);
        if b.seq != a.seq + 1 || c.seq != b.seq + 1 {
            continue;
        }
        // Evenly spaced and close: the middle sample is the midpoint in link angles.
        let ok = (0..3).all(|k| {
            let step = (c.theta_deg[k] - a.theta_deg[k]).abs();
            (a.theta_deg[k] + c.theta_deg[k] - 2.0 * b.theta_deg[k]).abs() < 0.2 * step.max(0.5) && step < 12.0
        });
        if !ok {
            continue;
        }
        for k in 0..6 {
            d2[k / 3].push(res[i - 1][k] - 2.0 * res[i][k] + res[i + 1][k]);
        }
    }
    if d2[0].len() < 90 {
        return None;
    }
    let mad_sigma = |v: &mut Vec<f64>| {
        v.sort_by(|a, b| a.total_cmp(b));
        let med = v[v.len() / 2];
        let mut dev: Vec<f64> = v.iter().map(|x| (x - med).abs()).collect();
        dev.sort_by(|a, b| a.total_cmp(b));
        1.4826 * dev[dev.len() / 2] / 6f64.sqrt()
    };
    let n = d2[0].len() / 3;
    let (a, b) = (mad_sigma(&mut d2[0]), mad_sigma(&mut d2[1]));
    // An all-zero residual (e.g. noise-free data) has no scale: treat as no estimate.
    (a > 0.0 && b > 0.0).then_some((a, b, n))
}

/// The columns of every ripple `a sin(k theta_i) + b (cos(k theta_i) - 1)` of a link angle, as the
/// change of the weighted prediction (6 rows per sample): the model's sensitivity to that
/// link's angle times the ripple's shape.
pub fn ripple_columns(
    unit: &UnitModel,
    data: &Dataset,
    sigma: (f64, f64),
) -> Result<Vec<(usize, usize, [DVector<f64>; 2])>> {
    let n = data.len();
    let h = 1e-3;
    let r0 = residuals(unit, data)?;
    let mut out = vec![];
    for link in 0..3 {
        let mut shifted = data.clone();
        for s in &mut shifted.samples {
            s.theta_deg[link] += h;
        }
        // A link whose shifted readings cannot be evaluated contributes no ripple columns.
        let Ok(ri) = residuals(unit, &shifted) else { continue };
        let mut g = vec![0.0; 6 * n];
        for k in 0..n {
            for m in 0..6 {
                g[6 * k + m] = (ri[k][m] - r0[k][m]) / h / if m < 3 { sigma.0 } else { sigma.1 };
            }
        }
        for cycles in RIPPLE_CYCLES {
            let mut cs = DVector::zeros(6 * n);
            let mut cc = DVector::zeros(6 * n);
            for (k, smp) in data.samples.iter().enumerate() {
                // Zero at reading 0: homing re-zeroes the reading, so a ripple does not move
                // home. A ripple that did (cos k theta alone) would carry a constant link-angle
                // shift that the data-only derivative applies to every pose but not to home:
                // a spurious constant rotation that no ripple in the unit makes.
                let (si, co) = (cycles as f64 * smp.theta_deg[link].to_radians()).sin_cos();
                let co = co - 1.0;
                for m in 0..6 {
                    cs[6 * k + m] = g[6 * k + m] * si;
                    cc[6 * k + m] = g[6 * k + m] * co;
                }
            }
            out.push((link, cycles, [cs, cc]));
        }
    }
    Ok(out)
}

/// Best sinusoid with `cycles` per revolution of one link angle, fitted to the rotation
/// residual: (amplitude deg, link index). Over the ~100 deg a link travels, neighbouring
/// harmonics are far from orthogonal, so links are compared by the variance removed.
pub fn periodic(data: &Dataset, res: &[[f64; 6]], cycles: usize) -> (f64, usize) {
    let mut best = (0.0, 0, 0.0);
    for l in 0..3 {
        let (mut amp2, mut removed) = (0.0, 0.0);
        for ax in 0..3 {
            let (mut ss, mut sc, mut cc, mut ys, mut yc) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for (s, r) in data.samples.iter().zip(res) {
                let t = (cycles as f64) * s.theta_deg[l].to_radians();
                let (si, co) = t.sin_cos();
                ss += si * si;
                sc += si * co;
                cc += co * co;
                ys += r[ax] * si;
                yc += r[ax] * co;
            }
            let det = ss * cc - sc * sc;
            if !(det.abs() > 1e-9 * (ss * cc).max(1e-300)) {
                continue;
            }
            let a = (ys * cc - yc * sc) / det;
            let b = (yc * ss - ys * sc) / det;
            amp2 += a * a + b * b;
            removed += a * ys + b * yc;
        }
        if removed > best.2 {
            best = (amp2.sqrt(), l, removed);
        }
    }
    (best.0, best.1)
}

/// The columns of a slow drift of the measured orientation over the session: a rotation about
/// each base-frame axis growing linearly from the first sample (home is measured at the start)
/// to the last, as the change of the weighted rotation residual (6 rows per sample; the
/// residual is in the camera frame, so each axis is seen through the measured orientation).
/// None where the samples carry no time span.
pub fn drift_columns(data: &Dataset, sigma_rot: f64) -> Option<[DVector<f64>; 3]> {
    let t0 = data.samples.iter().map(|s| s.t_s).fold(f64::INFINITY, f64::min);
    let t1 = data.samples.iter().map(|s| s.t_s).fold(f64::NEG_INFINITY, f64::max);
    if !(t1 > t0) {
        return None;
    }
    let n = data.len();
    let mut cols = [DVector::zeros(6 * n), DVector::zeros(6 * n), DVector::zeros(6 * n)];
    for (k, s) in data.samples.iter().enumerate() {
        let f = (s.t_s - t0) / (t1 - t0);
        let r = abvs_eye::Pose::from_p6(&s.pose).r;
        for (axis, c) in cols.iter_mut().enumerate() {
            // R^T e_axis: a base-frame rotation on the left of R_rel, in the residual's frame.
            for m in 0..3 {
                c[6 * k + m] = f * r[(axis, m)] / sigma_rot;
            }
        }
    }
    Some(cols)
}

/// A ripple fitted with the model: the yardstick for structure no library effect describes.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct Harmonic {
    pub link: usize,
    /// Cycles per revolution of the fundamental.
    pub cycles: usize,
    /// Held-out chi-square (noise units) it removes beyond the model's own parameters.
    pub drop: f64,
    /// Link-angle amplitude (deg).
    pub amplitude_deg: f64,
    /// Amplitude of its second harmonic (2 x cycles), where the data need it (deg).
    pub second_harmonic_deg: Option<f64>,
}

/// Structure outside the library that the selection fitted with the model.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub enum Outside {
    Ripple(Harmonic),
    /// The measured orientation drifting over the session: rotation from the first to the last
    /// sample (deg) and the held-out chi-square it removes.
    Drift {
        end_deg: f64,
        drop: f64,
    },
}

/// Drift of the rotation residual over the session (deg from start to end).
fn drift(data: &Dataset, res: &[[f64; 6]]) -> f64 {
    let t: Vec<f64> = data.samples.iter().map(|s| s.t_s).collect();
    let tm = t.iter().sum::<f64>() / t.len().max(1) as f64;
    let span = t.iter().cloned().fold(f64::MIN, f64::max) - t.iter().cloned().fold(f64::MAX, f64::min);
    let den: f64 = t.iter().map(|ti| (ti - tm).powi(2)).sum();
    let mut d = 0.0;
    for ax in 0..3 {
        let num: f64 = t.iter().zip(res).map(|(ti, r)| (ti - tm) * r[ax]).sum();
        if den > 0.0 {
            d += (num / den * span).powi(2);
        }
    }
    d.sqrt()
}

/// Names the strongest structure left that no library effect explains: the outside structure
/// the selection fitted with the model (a ripple, with its harmonic, or a drift; significant on
/// held-out data), a drift of the residual over the session, or else the plain statement that
/// structure remains.
pub fn describe(data: &Dataset, res: &[[f64; 6]], outside: Option<Outside>, sigma_rot: f64) -> String {
    let dr = drift(data, res);
    match outside {
        Some(Outside::Ripple(h)) if h.amplitude_deg > 0.5 * sigma_rot => {
            let second = h
                .second_harmonic_deg
                .map(|a| format!(", with its second harmonic ({} cycles, {a:.3} deg)", 2 * h.cycles))
                .unwrap_or_default();
            format!(
                "periodic in theta{}, {} cycles per revolution, {:.3} deg of link angle{second}",
                h.link + 1,
                h.cycles,
                h.amplitude_deg
            )
        }
        Some(Outside::Drift { end_deg, .. }) if end_deg > sigma_rot => {
            format!("drift of the measured orientation over the session, {end_deg:.3} deg from start to end")
        }
        _ if dr > 3.0 * sigma_rot => format!("drift over the session, {dr:.3} deg from start to end"),
        _ => "structured residual without a periodic or temporal pattern; see the residual heatmap".to_string(),
    }
}
