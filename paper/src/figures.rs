//! Fig. 7 (test error vs fine-tuning size, split by the PSC threshold) and Fig. 8 (MPE maps over
//! the commanded workspace).
use crate::config::PaperConfig;
use crate::error::Result;
use crate::scored::{Scored, TestSet};
use crate::summary::{Fig7Point, Fig8Map};
use abvs_eye::WORKSPACE_DEG;
use abvs_plot::workspace::{ALPHA_LABEL, GAMMA_LABEL};
use abvs_plot::{Heatmap, Reduce, Series, SeriesStyle, WorkspaceGrid, XyPlot};
use std::path::Path;

/// Fig. 8 cell size (deg).
const CELL_DEG: f64 = 2.0;
/// Fig. 8 regions for "grows from the centre outwards": max(|alpha|, |gamma|) of the cell centre.
pub(crate) const CENTRE_DEG: f64 = 10.0;
pub(crate) const OUTER_DEG: f64 = 20.0;

pub(crate) fn plot_fig7(out: &Path, pts: &[Fig7Point], cfg: &PaperConfig) -> Result<Vec<String>> {
    let mut files = vec![];
    for unit in &cfg.finetune_units {
        let mut labels = vec![];
        let mut series_pts = vec![];
        for method in ["M4f", "M2f", "hybrid"] {
            for (region, get) in [("internal", 0), ("external", 1)] {
                let p: Vec<(f64, f64)> = pts
                    .iter()
                    .filter(|p| &p.unit == unit && p.label == method)
                    .map(|p| (p.samples as f64, if get == 0 { p.mse_internal } else { p.mse_external }))
                    .collect();
                labels.push(format!("{method}, {region}"));
                series_pts.push(p);
            }
        }
        let series = labels
            .iter()
            .zip(series_pts)
            .map(|(l, points)| Series { label: l.as_str(), points, style: SeriesStyle::LinePoints })
            .collect();
        let title = format!("Fig. 7 ({unit}): test MSE_total vs fine-tuning size");
        let file = format!("fig7_{}.png", unit.to_lowercase());
        let plot = XyPlot {
            title: &title,
            x_label: "fine-tuning samples",
            y_label: "MSE_total (deg^2, mm^2)",
            series,
            log_y: true,
        };
        abvs_plot::xy_plot(&out.join(&file), &plot)?;
        files.push(file);
    }
    Ok(files)
}

/// Mean of per-sample values over the workspace grid (`CELL_DEG` cells; the edge poses at +-30
/// join the outermost cells): gamma centres, alpha centres, values.
fn cells(test: &TestSet, v: &[f64]) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let grid = WorkspaceGrid::new(CELL_DEG, WORKSPACE_DEG[0], WORKSPACE_DEG[2]);
    let pts: Vec<(f64, f64, f64)> = test.cmd.iter().zip(v).map(|(c, &x)| (c[0], c[2], x)).collect();
    grid.cells(&pts, Reduce::Mean)
}

pub(crate) fn plot_fig8(
    out: &Path,
    stem: &str,
    unit: &str,
    test: &TestSet,
    maps: &[(String, &Scored)],
) -> Result<Vec<Fig8Map>> {
    let grids: Vec<_> = maps.iter().map(|(_, s)| cells(test, &s.mpe)).collect();
    // One colour scale per figure so that the maps compare.
    let hi = grids.iter().flat_map(|g| g.2.iter()).copied().filter(|v| v.is_finite()).fold(0.0, f64::max);
    let range = (0.0, hi.max(1e-6));
    let mut res = vec![];
    for ((label, s), (x, y, values)) in maps.iter().zip(grids) {
        let slug: String =
            label.chars().map(|c| if c.is_ascii_alphanumeric() { c.to_ascii_lowercase() } else { '_' }).collect();
        let slug = slug.split('_').filter(|p| !p.is_empty()).collect::<Vec<_>>().join("_");
        let file = format!("{stem}_{slug}.png");
        let title = format!("{unit}, {label}: MPE (mean over beta)");
        let region = |keep: &dyn Fn(f64) -> bool| {
            let mut v = vec![];
            for (iy, gy) in y.iter().enumerate() {
                for (ix, gx) in x.iter().enumerate() {
                    let c = values[iy * x.len() + ix];
                    if c.is_finite() && keep(gx.abs().max(gy.abs())) {
                        v.push(c);
                    }
                }
            }
            v.iter().sum::<f64>() / v.len().max(1) as f64
        };
        let (centre, outer) = (region(&|m| m <= CENTRE_DEG), region(&|m| m > OUTER_DEG));
        let h = Heatmap {
            title: &title,
            x_label: GAMMA_LABEL,
            y_label: ALPHA_LABEL,
            colorbar_label: "MPE (px)",
            x,
            y,
            values,
            range: Some(range),
        };
        abvs_plot::heatmap(&out.join(&file), &h)?;
        res.push(Fig8Map {
            figure: stem.into(),
            unit: unit.into(),
            label: label.clone(),
            file,
            mean_mpe_px: s.result.eval.mpe_px,
            centre_mpe_px: centre,
            outer_mpe_px: outer,
            colour_range_px: range,
        });
    }
    Ok(res)
}
