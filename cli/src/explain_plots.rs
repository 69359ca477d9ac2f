//! PNG figures of the discrepancy report: held-out residual heatmaps over the workspace before
//! and after each step (the paper's Fig. 8 layout, alpha x gamma, mean over beta), and the
//! residual against the variable that explains each step.
use abvs_calib::explain::{explaining_variable, ExplainResult};
use abvs_eye::dataset::Dataset;
use abvs_eye::unit::{Effect, MotionHistory};
use abvs_plot::{heatmap, side_by_side, xy_plot, Heatmap, Reduce, Series, SeriesStyle, XyPlot};
use std::path::Path;

fn rot_norm(r: &[f64; 6]) -> f64 {
    (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt()
}

/// The workspace coordinates of a sample: commanded angles when recorded, else measured.
fn alpha_gamma(data: &Dataset) -> Vec<(f64, f64)> {
    data.samples.iter().map(|s| s.cmd_deg.map(|c| (c[0], c[2])).unwrap_or((s.pose[0], s.pose[2]))).collect()
}

/// Cell size: the dataset's grid step when it has one (>= 2 deg), else 3 deg.
fn cell_step(ag: &[(f64, f64)]) -> f64 {
    let mut d: Vec<f64> = ag.windows(2).map(|w| (w[1].1 - w[0].1).abs()).filter(|d| *d > 0.5).collect();
    d.sort_by(|a, b| a.total_cmp(b));
    d.get(d.len() / 2).copied().unwrap_or(3.0).max(2.0)
}

fn map<'a>(title: &'a str, ag: &[(f64, f64)], res: &[[f64; 6]], step: f64) -> Heatmap<'a> {
    let pts: Vec<(f64, f64, f64)> = ag.iter().zip(res).map(|(p, r)| (p.0, p.1, rot_norm(r))).collect();
    crate::plot::workspace_map(title, "held-out rotation residual, deg (mean over roll)", &pts, step, Reduce::Mean)
}

/// The variable a step's effect depends on, per sample, with its axis label.
fn variable(e: Effect, data: &Dataset, params: &[f64]) -> (Vec<f64>, String) {
    // The link the effect is largest on.
    let link = (0..3)
        .max_by(|&a, &b| params.get(a).unwrap_or(&0.0).abs().total_cmp(&params.get(b).unwrap_or(&0.0).abs()))
        .unwrap_or(0);
    match e {
        Effect::HingeBacklash => {
            let mut h = MotionHistory::new();
            let v = data.samples.iter().map(|s| h.update(&s.theta_deg)[link] + s.theta_deg[link] / 200.0).collect();
            (v, format!("direction link {} last moved (-1 / +1; spread by its angle)", link + 1))
        }
        Effect::CodeWheelEccentricity | Effect::EncoderScale | Effect::EncoderZeroOffset => {
            (data.samples.iter().map(|s| s.theta_deg[link]).collect(), format!("theta{} (deg)", link + 1))
        }
        Effect::GravitySag => (
            data.samples.iter().map(|s| s.pose[0]).collect(),
            "alpha (pitch, deg): lever of the camera's weight".into(),
        ),
        _ => (data.samples.iter().map(|s| s.pose[0]).collect(), "alpha (pitch), deg".into()),
    }
}

/// Writes the report's PNGs into `dir`; returns (title, file name) pairs.
pub fn write(dir: &Path, data: &Dataset, r: &ExplainResult) -> anyhow::Result<Vec<(String, String)>> {
    let ag = alpha_gamma(data);
    let step = cell_step(&ag);
    let mut out = vec![];
    for (i, s) in r.steps.iter().enumerate() {
        let e = Effect::from_name(&s.effect)?;
        let file = format!("step{}_{}_heatmap.png", i + 1, s.effect);
        let (tb, ta) = (format!("before {}", s.effect), format!("after {}", s.effect));
        side_by_side(
            &dir.join(&file),
            &map(&tb, &ag, &s.heldout_before, step),
            &map(&ta, &ag, &s.heldout_after, step),
        )?;
        out.push((format!("step {}: held-out residual before / after {}", i + 1, s.effect), file));

        let params: Vec<f64> = s.params.values().copied().collect();
        let (x, xl) = variable(e, data, &params);
        // The residual along the direction the effect explains (the principal axis of the
        // per-sample change), binned over the explaining variable: its signature before, flat after.
        let mut m = nalgebra::Matrix3::<f64>::zeros();
        for (b, a) in s.heldout_before.iter().zip(&s.heldout_after) {
            let d = nalgebra::Vector3::new(b[0] - a[0], b[1] - a[1], b[2] - a[2]);
            m += d * d.transpose();
        }
        let eig = nalgebra::SymmetricEigen::new(m);
        let k = (0..3).max_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j])).unwrap_or(0);
        let u = eig.eigenvectors.column(k).into_owned();
        let along = |res: &[[f64; 6]]| -> Vec<(f64, f64)> {
            binned(&x, &res.iter().map(|r| r[0] * u[0] + r[1] * u[1] + r[2] * u[2]).collect::<Vec<_>>(), 30)
        };
        let file = format!("step{}_{}_vs_variable.png", i + 1, s.effect);
        let title = format!("held-out residual vs {}", explaining_variable(e));
        xy_plot(
            &dir.join(&file),
            &XyPlot {
                title: &title,
                x_label: &xl,
                y_label: "rotation residual along the effect's direction, deg (bin mean)",
                series: vec![
                    Series { label: "before", points: along(&s.heldout_before), style: SeriesStyle::LinePoints },
                    Series { label: "after", points: along(&s.heldout_after), style: SeriesStyle::LinePoints },
                ],
                log_y: false,
            },
        )?;
        out.push((format!("step {}: residual vs {}", i + 1, explaining_variable(e)), file));
    }
    let file = "final_residual_heatmap.png".to_string();
    heatmap(&dir.join(&file), &map("held-out residual, final model", &ag, &r.final_heldout, step))?;
    out.push(("final model: held-out residual over the workspace".into(), file));
    Ok(out)
}

/// Means of `y` in `bins` equal-width bins of `x` (empty bins skipped).
fn binned(x: &[f64], y: &[f64], bins: usize) -> Vec<(f64, f64)> {
    let (lo, hi) = x.iter().fold((f64::MAX, f64::MIN), |(l, h), v| (l.min(*v), h.max(*v)));
    let w = ((hi - lo) / bins as f64).max(1e-12);
    let mut acc = vec![(0.0, 0usize); bins];
    for (a, b) in x.iter().zip(y) {
        let k = (((a - lo) / w) as usize).min(bins - 1);
        acc[k].0 += b;
        acc[k].1 += 1;
    }
    acc.iter()
        .enumerate()
        .filter(|(_, c)| c.1 > 0)
        .map(|(k, c)| (lo + (k as f64 + 0.5) * w, c.0 / c.1 as f64))
        .collect()
}
