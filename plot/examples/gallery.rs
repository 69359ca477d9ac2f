//! Writes one plot of each kind into a directory, to look at:
//! `cargo run -p abvs-plot --example gallery -- /tmp/abvs-plot`

use std::path::PathBuf;

use abvs_plot::{grid_cells, Heatmap, Reduce, Series, SeriesStyle, XyPlot};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "/tmp/abvs-plot".into()));
    std::fs::create_dir_all(&dir)?;
    if let Some(w) = abvs_plot::font_warning() {
        eprintln!("{w}");
    }

    // Scattered "measurements" over alpha +-30, beta +-15, binned at 3 deg.
    let mut pts = Vec::new();
    for i in 0..4000 {
        let (a, b) = ((i * 37 % 601) as f64 / 10.0 - 30.0, (i * 53 % 301) as f64 / 10.0 - 15.0);
        if (a - 20.0).powi(2) + (b + 10.0).powi(2) < 16.0 {
            continue; // a hole: cells with no data
        }
        pts.push((a, b, 0.02 + 0.001 * (a * a + 3.0 * b * b).sqrt() + 0.01 * (a / 7.0).sin()));
    }
    let (x, y, values) = grid_cells(&pts, 3.0, Reduce::Mean);
    let before = Heatmap {
        title: "Pointing error, nominal kinematics",
        x_label: "alpha (deg)",
        y_label: "beta (deg)",
        colorbar_label: "error (deg)",
        x,
        y,
        values,
        range: None,
    };
    abvs_plot::heatmap(&dir.join("heatmap.png"), &before)?;
    let after = Heatmap {
        title: "Pointing error, calibrated",
        values: before.values.iter().map(|v| v * 0.3).collect(),
        ..before.clone()
    };
    abvs_plot::side_by_side(&dir.join("side_by_side.png"), &before, &after)?;

    // Signed, tiny values: scientific colour-bar labels must still fit.
    let signed = Heatmap {
        title: "Residual about gamma",
        colorbar_label: "residual (rad)",
        values: before.values.iter().enumerate().map(|(i, v)| (v - 0.04) * 1.5e-2 * (i as f64 * 0.1).cos()).collect(),
        ..before.clone()
    };
    abvs_plot::heatmap(&dir.join("heatmap_small.png"), &signed)?;

    let curve =
        |k: f64| -> Vec<(f64, f64)> { (1..=15).map(|i| (i as f64 * 40.0, k / (i as f64 * 40.0).sqrt())).collect() };
    let plot = XyPlot {
        title: "Calibration error vs sample size",
        x_label: "samples",
        y_label: "RMS error (deg)",
        series: vec![
            Series { label: "nominal", points: curve(1.0), style: SeriesStyle::LinePoints },
            Series { label: "calibrated", points: curve(0.2), style: SeriesStyle::Line },
            Series { label: "held-out", points: curve(0.35), style: SeriesStyle::Points },
        ],
        log_y: true,
    };
    abvs_plot::xy_plot(&dir.join("xy_log.png"), &plot)?;
    let resid = XyPlot {
        title: "Residuals",
        x_label: "sample",
        y_label: "residual (deg)",
        series: vec![Series {
            label: "alpha",
            points: (0..200).map(|i| (i as f64, 1e-4 * ((i as f64) * 0.7).sin())).collect(),
            style: SeriesStyle::Points,
        }],
        log_y: false,
    };
    abvs_plot::xy_plot(&dir.join("xy_lin.png"), &resid)?;
    println!("wrote {}", dir.display());
    Ok(())
}
