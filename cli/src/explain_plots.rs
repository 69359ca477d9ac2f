//! PNG figures of the discrepancy report: held-out residual heatmaps over the workspace before
//! and after each step (the paper's Fig. 8 layout, alpha x gamma, mean over beta), and the
//! residual against the variable that explains each step.
use abvs_calib::explain::{explaining_variable, ExplainResult};
use abvs_eye::dataset::Dataset;
use abvs_eye::unit::{Effect, MotionHistory};
use abvs_plot::{grid_cells, heatmap, side_by_side, xy_plot, Heatmap, Reduce, Series, SeriesStyle, XyPlot};
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
    let pts: Vec<(f64, f64, f64)> = ag.iter().zip(res).map(|(p, r)| (p.1, p.0, rot_norm(r))).collect();
    let (x, y, values) = grid_cells(&pts, step, Reduce::Mean);
    Heatmap {
        title,
        x_label: "gamma (yaw), deg",
        y_label: "alpha (pitch), deg",
        colorbar_label: "held-out rotation residual, deg",
        x,
        y,
        values,
        range: None,
    }
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
            let v =
                data.samples.iter().map(|s| h.update(&s.theta_deg)[link] * 0.5 + s.theta_deg[link] / 400.0).collect();
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
        let pts = |res: &[[f64; 6]]| x.iter().zip(res).map(|(a, r)| (*a, rot_norm(r))).collect::<Vec<_>>();
        let file = format!("step{}_{}_vs_variable.png", i + 1, s.effect);
        let title = format!("held-out residual vs {}", explaining_variable(e));
        xy_plot(
            &dir.join(&file),
            &XyPlot {
                title: &title,
                x_label: &xl,
                y_label: "rotation residual, deg",
                series: vec![
                    Series { label: "before", points: pts(&s.heldout_before), style: SeriesStyle::Points },
                    Series { label: "after", points: pts(&s.heldout_after), style: SeriesStyle::Points },
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
