//! Each plot function writes a decodable PNG of the documented size with real content, and
//! bad input gives errors that name the file.

use std::path::{Path, PathBuf};

use abvs_plot::{
    grid_cells, heatmap, side_by_side, xy_plot, Heatmap, PlotError, Reduce, Series, SeriesStyle, XyPlot, PAIR_SIZE,
    PLOT_SIZE,
};

/// Decodes the PNG and checks its size and that it is not blank.
fn check_png(path: &Path, size: (u32, u32)) {
    let img = image::open(path).unwrap_or_else(|e| panic!("{}: not a PNG: {e}", path.display())).to_rgb8();
    assert_eq!(img.dimensions(), size, "{}", path.display());
    let first = img.get_pixel(0, 0);
    let distinct = img.pixels().filter(|p| *p != first).count();
    assert!(distinct > 1000, "{}: nearly one colour", path.display());
}

/// A smooth bowl over a Fick-like workspace with a few empty cells.
fn workspace_map(scale: f64) -> Heatmap<'static> {
    let x: Vec<f64> = (-10..=10).map(|i| i as f64 * 3.0).collect();
    let y: Vec<f64> = (-5..=5).map(|i| i as f64 * 3.0).collect();
    let mut values = Vec::new();
    for (iy, yv) in y.iter().enumerate() {
        for (ix, xv) in x.iter().enumerate() {
            values.push(if (ix + 2 * iy) % 17 == 0 {
                f64::NAN
            } else {
                scale * (xv * xv + 4.0 * yv * yv).sqrt() / 1000.0
            });
        }
    }
    Heatmap {
        title: "Residual",
        x_label: "alpha (deg)",
        y_label: "beta (deg)",
        colorbar_label: "error (deg)",
        x,
        y,
        values,
        range: None,
    }
}

fn xy(log_y: bool, n_series: usize) -> XyPlot<'static> {
    let labels = ["nominal", "calibrated", "true model"];
    let styles = [SeriesStyle::LinePoints, SeriesStyle::Line, SeriesStyle::Points];
    XyPlot {
        title: "Error vs sample size",
        x_label: "samples",
        y_label: "RMS error (deg)",
        series: (0..n_series)
            .map(|k| Series {
                label: labels[k],
                points: (1..=20)
                    .map(|i| {
                        let n = 50.0 * i as f64;
                        (n, (k as f64 + 1.0) * 0.5 / n.sqrt())
                    })
                    .collect(),
                style: styles[k],
            })
            .collect(),
        log_y,
    }
}

fn out(dir: &tempfile::TempDir, name: &str) -> PathBuf {
    dir.path().join(name)
}

#[test]
fn heatmap_writes_png_with_nan_cells() {
    let dir = tempfile::tempdir().unwrap();
    let p = out(&dir, "heat.png");
    heatmap(&p, &workspace_map(1.0)).unwrap();
    check_png(&p, PLOT_SIZE);
}

#[test]
fn heatmap_with_given_range_and_single_cell() {
    let dir = tempfile::tempdir().unwrap();
    let mut h = workspace_map(1.0);
    h.range = Some((0.0, 0.01)); // data exceed it: clamped, not an error
    let p = out(&dir, "ranged.png");
    heatmap(&p, &h).unwrap();
    check_png(&p, PLOT_SIZE);

    let one = Heatmap { x: vec![0.0], y: vec![0.0], values: vec![2.0], range: None, ..workspace_map(1.0) };
    let p = out(&dir, "one.png");
    heatmap(&p, &one).unwrap();
    check_png(&p, PLOT_SIZE);
}

#[test]
fn side_by_side_writes_wide_png() {
    let dir = tempfile::tempdir().unwrap();
    let p = out(&dir, "pair.png");
    let mut after = workspace_map(0.2);
    after.title = "After calibration";
    side_by_side(&p, &workspace_map(1.0), &after).unwrap();
    check_png(&p, PAIR_SIZE);
}

#[test]
fn xy_plot_linear_log_and_single_series() {
    let dir = tempfile::tempdir().unwrap();
    for (name, plot) in [("lin.png", xy(false, 3)), ("log.png", xy(true, 3)), ("one.png", xy(false, 1))] {
        let p = out(&dir, name);
        xy_plot(&p, &plot).unwrap();
        check_png(&p, PLOT_SIZE);
    }
}

#[test]
fn xy_plot_log_skips_non_positive_points() {
    let dir = tempfile::tempdir().unwrap();
    let mut plot = xy(true, 2);
    plot.series[0].points.push((1100.0, 0.0));
    plot.series[1].points.push((1100.0, f64::NAN));
    let p = out(&dir, "log0.png");
    xy_plot(&p, &plot).unwrap();
    check_png(&p, PLOT_SIZE);
}

fn assert_names_path(e: &PlotError, p: &Path) {
    let msg = e.to_string();
    assert!(msg.contains(&p.display().to_string()), "{msg}");
}

#[test]
fn unwritable_path_is_an_error_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("no such dir").join("heat.png");
    let e = heatmap(&p, &workspace_map(1.0)).unwrap_err();
    assert!(matches!(e, PlotError::Write { .. }), "{e:?}");
    assert_names_path(&e, &p);
    let e = xy_plot(&p, &xy(false, 2)).unwrap_err();
    assert!(matches!(e, PlotError::Write { .. }), "{e:?}");
    let e = side_by_side(&p, &workspace_map(1.0), &workspace_map(1.0)).unwrap_err();
    assert!(matches!(e, PlotError::Write { .. }), "{e:?}");
}

#[test]
fn empty_data_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let p = out(&dir, "empty.png");
    let empty = Heatmap { x: vec![], y: vec![], values: vec![], ..workspace_map(1.0) };
    for e in [
        heatmap(&p, &empty).unwrap_err(),
        side_by_side(&p, &workspace_map(1.0), &empty).unwrap_err(),
        xy_plot(&p, &XyPlot { series: vec![], ..xy(false, 1) }).unwrap_err(),
    ] {
        assert!(matches!(e, PlotError::Empty { .. }), "{e:?}");
        assert_names_path(&e, &p);
    }
    let mut no_points = xy(false, 2);
    no_points.series.iter_mut().for_each(|s| s.points.clear());
    let e = xy_plot(&p, &no_points).unwrap_err();
    assert!(matches!(e, PlotError::Empty { .. }), "{e}");

    // Only non-positive y on a log axis: nothing drawable.
    let mut neg = xy(true, 1);
    neg.series[0].points = vec![(1.0, -1.0), (2.0, 0.0)];
    let e = xy_plot(&p, &neg).unwrap_err();
    assert!(e.to_string().contains("log"), "{e}");

    // All cells empty and no range given: no colour scale to draw.
    let mut all_nan = workspace_map(1.0);
    all_nan.values.iter_mut().for_each(|v| *v = f64::NAN);
    let e = heatmap(&p, &all_nan).unwrap_err();
    assert!(matches!(e, PlotError::Empty { .. }), "{e}");
    // With a range it is a valid (all grey) plot.
    all_nan.range = Some((0.0, 1.0));
    heatmap(&p, &all_nan).unwrap();
    check_png(&p, PLOT_SIZE);
}

#[test]
fn inconsistent_heatmap_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let p = out(&dir, "bad.png");
    let mut h = workspace_map(1.0);
    h.values.pop();
    let e = heatmap(&p, &h).unwrap_err();
    assert!(matches!(e, PlotError::Invalid { .. }), "{e}");
    assert_names_path(&e, &p);

    let mut h = workspace_map(1.0);
    h.x.reverse();
    assert!(matches!(heatmap(&p, &h), Err(PlotError::Invalid { .. })));

    let mut h = workspace_map(1.0);
    h.range = Some((1.0, f64::NAN));
    assert!(matches!(heatmap(&p, &h), Err(PlotError::Invalid { .. })));
    assert!(!p.exists(), "nothing written for invalid input");
}

#[test]
fn grid_cells_mean_and_max() {
    // step 2: cells centred on ..., -2, 0, 2, 4; x in -2..=4 (4 cells), y in 0..=2 (2 cells).
    let pts = [
        (0.1, 0.2, 1.0),      // cell (0, 0)
        (-0.4, 0.9, 3.0),     // cell (0, 0)
        (-2.2, 0.0, 5.0),     // cell (-2, 0)
        (3.9, 2.1, 7.0),      // cell (4, 2)
        (4.2, 1.5, -1.0),     // cell (4, 2)
        (2.0, 2.0, f64::NAN), // skipped
        (f64::NAN, 0.0, 9.0), // skipped
    ];
    let (x, y, mean) = grid_cells(&pts, 2.0, Reduce::Mean);
    assert_eq!(x, vec![-2.0, 0.0, 2.0, 4.0]);
    assert_eq!(y, vec![0.0, 2.0]);
    let nan = f64::NAN;
    let same =
        |a: &[f64], b: &[f64]| a.len() == b.len() && a.iter().zip(b).all(|(p, q)| (p.is_nan() && q.is_nan()) || p == q);
    let want_mean = [5.0, 2.0, nan, nan, nan, nan, nan, 3.0];
    assert!(same(&mean, &want_mean), "{mean:?}");
    let (x2, y2, max) = grid_cells(&pts, 2.0, Reduce::Max);
    assert_eq!((x2, y2), (x, y));
    let want_max = [5.0, 3.0, nan, nan, nan, nan, nan, 7.0];
    assert!(same(&max, &want_max), "{max:?}");

    let (x, y, v) = grid_cells(&[], 1.0, Reduce::Mean);
    assert!(x.is_empty() && y.is_empty() && v.is_empty());
}

#[test]
fn grid_cells_output_plots() {
    let pts: Vec<(f64, f64, f64)> = (0..200)
        .map(|i| {
            let (a, b) = ((i % 20) as f64 * 3.0 - 30.0, (i / 20) as f64 * 3.0 - 15.0);
            (a, b, a.abs() + b.abs())
        })
        .collect();
    let (x, y, values) = grid_cells(&pts, 3.0, Reduce::Max);
    let dir = tempfile::tempdir().unwrap();
    let p = out(&dir, "binned.png");
    heatmap(&p, &Heatmap { x, y, values, range: None, ..workspace_map(1.0) }).unwrap();
    check_png(&p, PLOT_SIZE);
}

#[test]
fn a_font_is_found_and_the_title_is_drawn() {
    // No font is embedded: Debian's fonts-dejavu-core (scripts/setup.sh) or $ABVS_FONT provides it. A machine
    // without one fails here, naming what to install (this test used to pass silently there).
    assert_eq!(
        abvs_plot::font_warning(),
        None,
        "no font for plot text: install fonts-dejavu-core (scripts/setup.sh) or set ABVS_FONT to a .ttf"
    );
    // The title is really drawn: dark pixels in the strip above the map.
    let dir = tempfile::tempdir().unwrap();
    let p = out(&dir, "title.png");
    heatmap(&p, &workspace_map(1.0)).unwrap();
    let img = image::open(&p).unwrap().to_rgb8();
    let dark = (200..600)
        .flat_map(|x| (0..30).map(move |y| (x, y)))
        .filter(|&(x, y)| img.get_pixel(x, y).0.iter().all(|&c| c < 100))
        .count();
    assert!(dark > 100, "only {dark} dark pixels where the title should be");
}

/// Pixels close to viridis' top colour (yellow) in columns `x0..x1`.
fn yellow_pixels(img: &image::RgbImage, x0: u32, x1: u32) -> usize {
    let near = |a: u8, b: u8| a.abs_diff(b) < 12;
    (x0..x1)
        .flat_map(|x| (0..img.height()).map(move |y| (x, y)))
        .filter(|&(x, y)| {
            let p = img.get_pixel(x, y).0;
            near(p[0], 0xfd) && near(p[1], 0xe7) && near(p[2], 0x25)
        })
        .count()
}

#[test]
fn side_by_side_shares_the_colour_scale() {
    let map = |hi: f64| Heatmap {
        x: vec![0.0, 1.0],
        y: vec![0.0, 1.0],
        values: vec![0.0, hi, 0.0, hi],
        range: None,
        ..workspace_map(1.0)
    };
    let dir = tempfile::tempdir().unwrap();
    let p = out(&dir, "shared.png");
    side_by_side(&p, &map(1.0), &map(0.2)).unwrap();
    let img = image::open(&p).unwrap().to_rgb8();
    let half = PAIR_SIZE.0 / 2;
    let (left, right) = (yellow_pixels(&img, 0, half), yellow_pixels(&img, half, PAIR_SIZE.0));
    // Left: half its map is yellow; right: only the top of its colour bar.
    assert!(left > 50_000 && right < 2_000, "yellow pixels left {left}, right {right}");
}
