//! The one grid of the workspace heatmaps (the paper's Fig. 8 and every `abvs` map over the
//! gaze): commanded gamma (yaw) across, alpha (pitch) up, cells of `step` degrees tiling
//! [-range, range] on each axis from -range (a pose on the +range edge joins the outermost
//! cell; poses beyond the range join the edge cells).
use crate::{Heatmap, Reduce};

/// Axis labels of every workspace map.
pub const GAMMA_LABEL: &str = "commanded gamma (yaw), deg";
pub const ALPHA_LABEL: &str = "commanded alpha (pitch), deg";

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorkspaceGrid {
    /// Cell size, deg.
    pub step_deg: f64,
    /// Half-ranges of alpha and gamma, deg (the workspace: 30, 30).
    pub alpha_range_deg: f64,
    pub gamma_range_deg: f64,
}

impl WorkspaceGrid {
    pub fn new(step_deg: f64, alpha_range_deg: f64, gamma_range_deg: f64) -> Self {
        assert!(step_deg.is_finite() && step_deg > 0.0, "workspace grid: step must be finite and > 0, got {step_deg}");
        WorkspaceGrid { step_deg, alpha_range_deg, gamma_range_deg }
    }

    fn n(&self, r: f64) -> usize {
        ((2.0 * r / self.step_deg).round() as usize).max(1)
    }

    fn index(&self, c: f64, r: f64) -> usize {
        (((c + r) / self.step_deg).floor().max(0.0) as usize).min(self.n(r) - 1)
    }

    fn centres(&self, r: f64) -> Vec<f64> {
        (0..self.n(r)).map(|k| -r + self.step_deg * (k as f64 + 0.5)).collect()
    }

    /// Cell centres across (gamma), up (alpha), and the cell values, `values[i_alpha * n_gamma +
    /// i_gamma]`, of `(alpha, gamma, value)` points reduced per cell (NaN: an empty cell).
    /// Points with a non-finite coordinate or value are skipped.
    pub fn cells(&self, points: &[(f64, f64, f64)], reduce: Reduce) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        let (ra, rg) = (self.alpha_range_deg, self.gamma_range_deg);
        let ng = self.n(rg);
        let items = points
            .iter()
            .filter(|(a, g, v)| a.is_finite() && g.is_finite() && v.is_finite())
            .map(|&(a, g, v)| (self.index(a, ra) * ng + self.index(g, rg), v));
        let values = crate::reduce_cells(self.n(ra) * ng, items, reduce);
        (self.centres(rg), self.centres(ra), values)
    }

    /// A heatmap of `(alpha, gamma, value)` points on this grid.
    pub fn heatmap<'a>(
        &self,
        title: &'a str,
        colorbar_label: &'a str,
        points: &[(f64, f64, f64)],
        reduce: Reduce,
    ) -> Heatmap<'a> {
        let (x, y, values) = self.cells(points, reduce);
        Heatmap { title, x_label: GAMMA_LABEL, y_label: ALPHA_LABEL, colorbar_label, x, y, values, range: None }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gamma_across_alpha_up_edges_join_the_outer_cells() {
        let g = WorkspaceGrid::new(2.0, 30.0, 30.0);
        let pts = [(-30.0, 0.5, 1.0), (-29.0, 0.5, 3.0), (30.0, -30.0, 5.0), (0.0, 29.9, f64::NAN)];
        let (x, y, v) = g.cells(&pts, Reduce::Mean);
        assert_eq!((x.len(), y.len(), v.len()), (30, 30, 900));
        assert_eq!((x[0], y[29]), (-29.0, 29.0));
        // alpha -30 and -29 share row 0; gamma 0.5 is column 15.
        assert_eq!(v[15], 2.0);
        // alpha +30 joins the last row; gamma -30 the first column.
        assert_eq!(v[29 * 30], 5.0);
        assert_eq!(v.iter().filter(|c| c.is_finite()).count(), 2);
        let (_, _, m) = g.cells(&pts, Reduce::Max);
        assert_eq!(m[15], 3.0);
    }
}
