//! Workspace heatmaps (the paper's Fig. 8 layout: gamma across, alpha down) over abvs-plot.
use abvs_plot::{grid_cells, heatmap, Heatmap, Reduce};
use std::path::Path;

/// A heatmap of `(alpha, gamma, value)` points binned on `step` degree cells.
pub fn workspace_map<'a>(
    title: &'a str,
    colorbar_label: &'a str,
    points: &[(f64, f64, f64)],
    step: f64,
    reduce: Reduce,
) -> Heatmap<'a> {
    let pts: Vec<(f64, f64, f64)> = points.iter().map(|&(a, g, v)| (g, a, v)).collect();
    let (x, y, values) = grid_cells(&pts, step, reduce);
    Heatmap {
        title,
        x_label: "gamma (yaw), deg",
        y_label: "alpha (pitch), deg",
        colorbar_label,
        x,
        y,
        values,
        range: None,
    }
}

/// Writes [`workspace_map`] as a PNG.
pub fn workspace_heatmap(
    path: &Path,
    title: &str,
    colorbar_label: &str,
    points: &[(f64, f64, f64)],
    step: f64,
    reduce: Reduce,
) -> anyhow::Result<()> {
    heatmap(path, &workspace_map(title, colorbar_label, points, step, reduce))?;
    Ok(())
}
