//! Workspace heatmaps over abvs-plot's one workspace grid (the paper's Fig. 8 layout: gamma
//! across, alpha up; cells tiling the workspace).
use abvs_eye::WORKSPACE_DEG;
use abvs_plot::{heatmap, Heatmap, Reduce, WorkspaceGrid};
use std::path::Path;

/// A heatmap of `(alpha, gamma, value)` points binned on `step` degree cells of the workspace.
pub fn workspace_map<'a>(
    title: &'a str,
    colorbar_label: &'a str,
    points: &[(f64, f64, f64)],
    step: f64,
    reduce: Reduce,
) -> Heatmap<'a> {
    WorkspaceGrid::new(step, WORKSPACE_DEG[0], WORKSPACE_DEG[2]).heatmap(title, colorbar_label, points, reduce)
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
