//! PNG plots for abvs results: heatmaps over the eye's workspace (with a colour bar), x-y
//! plots (residuals, error vs sample size; optional log y) and before/after heatmap pairs.
//!
//! Drawing is done by `plotters` into an RGB buffer, which the workspace's `image` crate
//! encodes as PNG. Text uses a TrueType font found at run time (see [`font_warning`]); with no
//! font the plots are still written, only without any text.

use std::path::{Path, PathBuf};

use ab_glyph::FontRef;
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::coord::Shift;
use plotters::prelude::*;

mod canvas;
mod font;
mod ticks;
pub mod workspace;

pub use font::font_warning;
pub use workspace::WorkspaceGrid;

/// Size of single plots ([`heatmap`], [`xy_plot`]).
pub const PLOT_SIZE: (u32, u32) = (800, 600);
/// Size of [`side_by_side`] plots.
pub const PAIR_SIZE: (u32, u32) = (1400, 600);

/// Errors of this crate; each names the PNG that could not be made.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    #[error("{}: nothing to plot: {what}", path.display())]
    Empty { path: PathBuf, what: String },
    #[error("{}: invalid plot data: {what}", path.display())]
    Invalid { path: PathBuf, what: String },
    #[error("{}: drawing failed: {msg}", path.display())]
    Draw { path: PathBuf, msg: String },
    #[error("{}: cannot encode PNG: {source}", path.display())]
    Encode {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
    #[error("{}: cannot write PNG: {source}", path.display())]
    Write {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

pub type Result<T> = std::result::Result<T, PlotError>;

/// A map of values on a regular grid of cells.
#[derive(Debug, Clone)]
pub struct Heatmap<'a> {
    pub title: &'a str,
    pub x_label: &'a str,
    pub y_label: &'a str,
    pub colorbar_label: &'a str,
    /// Cell centres along x, strictly increasing (normally regular).
    pub x: Vec<f64>,
    /// Cell centres along y, strictly increasing (normally regular).
    pub y: Vec<f64>,
    /// Row-major, y-major: `values[iy * x.len() + ix]`. Non-finite (NaN) = empty cell, drawn grey.
    pub values: Vec<f64>,
    /// Colour scale; `None` = data min..max. Give the same range to plots that are compared.
    pub range: Option<(f64, f64)>,
}

/// How [`grid_cells`] reduces the points that fall into one cell.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reduce {
    Mean,
    Max,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SeriesStyle {
    Line,
    Points,
    LinePoints,
}

/// One curve of an [`XyPlot`]. Non-finite points (and, on a log axis, y <= 0) are skipped.
#[derive(Debug, Clone)]
pub struct Series<'a> {
    pub label: &'a str,
    pub points: Vec<(f64, f64)>,
    pub style: SeriesStyle,
}

#[derive(Debug, Clone)]
pub struct XyPlot<'a> {
    pub title: &'a str,
    pub x_label: &'a str,
    pub y_label: &'a str,
    pub series: Vec<Series<'a>>,
    pub log_y: bool,
}

/// Writes `h` as an 800x600 PNG: viridis cells, axes, and a colour bar with tick labels.
pub fn heatmap(path: &Path, h: &Heatmap) -> Result<()> {
    let grid = Grid::new(path, h)?;
    let range = match h.range {
        Some(r) => checked_range(path, r)?,
        None => grid.data_range(path)?,
    };
    let font = font::font();
    let text = font.is_some();
    render(path, PLOT_SIZE, font, |root| draw_heatmap(root, h, &grid, range, text))
}

/// Writes two heatmaps next to each other in one 1400x600 PNG (e.g. residuals before and after
/// calibration). If both ranges are `None`, both use the union of the two data ranges so that
/// colours compare; otherwise each uses its own.
pub fn side_by_side(path: &Path, a: &Heatmap, b: &Heatmap) -> Result<()> {
    let (ga, gb) = (Grid::new(path, a)?, Grid::new(path, b)?);
    let (ra, rb) = match (a.range, b.range) {
        (None, None) => {
            let u = union_range(path, &[&ga, &gb])?;
            (u, u)
        }
        (ra, rb) => (
            ra.map_or_else(|| ga.data_range(path), |r| checked_range(path, r))?,
            rb.map_or_else(|| gb.data_range(path), |r| checked_range(path, r))?,
        ),
    };
    let font = font::font();
    let text = font.is_some();
    render(path, PAIR_SIZE, font, |root| {
        let (left, right) = root.split_horizontally(PAIR_SIZE.0 / 2);
        draw_heatmap(&left, a, &ga, ra, text)?;
        draw_heatmap(&right, b, &gb, rb, text)
    })
}

/// Bins scattered points `(x, y, v)` on a regular grid of `step` and reduces each cell with
/// mean or max. Cells are centred on multiples of `step` (a 3 deg data grid lands on cell
/// centres). Returns `(x, y, values)` ready for [`Heatmap`]: the centres span the occupied
/// cells, cells without points are NaN. Points with a non-finite coordinate or value are
/// skipped; no usable point gives three empty vectors.
///
/// # Panics
/// If `step` is not finite and positive (a programming error, not a data error).
pub fn grid_cells(points: &[(f64, f64, f64)], step: f64, reduce: Reduce) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    assert!(step.is_finite() && step > 0.0, "grid_cells: step must be finite and > 0, got {step}");
    let cell = |c: f64| (c / step).round() as i64;
    let used: Vec<(i64, i64, f64)> = points
        .iter()
        .filter(|(x, y, v)| x.is_finite() && y.is_finite() && v.is_finite())
        .map(|&(x, y, v)| (cell(x), cell(y), v))
        .collect();
    let (Some(ix0), Some(ix1), Some(iy0), Some(iy1)) = (
        used.iter().map(|p| p.0).min(),
        used.iter().map(|p| p.0).max(),
        used.iter().map(|p| p.1).min(),
        used.iter().map(|p| p.1).max(),
    ) else {
        return (Vec::new(), Vec::new(), Vec::new());
    };
    let (nx, ny) = ((ix1 - ix0 + 1) as usize, (iy1 - iy0 + 1) as usize);
    let values = reduce_cells(
        nx * ny,
        used.iter().map(|&(ix, iy, v)| ((iy - iy0) as usize * nx + (ix - ix0) as usize, v)),
        reduce,
    );
    let centres = |i0: i64, n: usize| (0..n).map(|k| (i0 + k as i64) as f64 * step).collect();
    (centres(ix0, nx), centres(iy0, ny), values)
}

/// Values of `n` cells from `(cell index, value)` items: their mean or max, NaN where a cell has none.
pub(crate) fn reduce_cells(n: usize, items: impl Iterator<Item = (usize, f64)>, reduce: Reduce) -> Vec<f64> {
    // Per cell: (sum or max, count).
    let mut acc = vec![(0.0f64, 0usize); n];
    for (i, v) in items {
        let (s, k) = &mut acc[i];
        *s = match (reduce, *k) {
            (Reduce::Max, 0) => v,
            (Reduce::Max, _) => s.max(v),
            (Reduce::Mean, _) => *s + v,
        };
        *k += 1;
    }
    acc.into_iter()
        .map(|(s, k)| match (k, reduce) {
            (0, _) => f64::NAN,
            (_, Reduce::Mean) => s / k as f64,
            (_, Reduce::Max) => s,
        })
        .collect()
}

/// Writes `p` as an 800x600 PNG: one colour per series, a legend when there is more than one,
/// ranges fitted to the data with a margin (whole decades on a log y axis).
pub fn xy_plot(path: &Path, p: &XyPlot) -> Result<()> {
    let keep = |&(x, y): &(f64, f64)| x.is_finite() && y.is_finite() && (!p.log_y || y > 0.0);
    let series: Vec<(&Series, Vec<(f64, f64)>)> =
        p.series.iter().map(|s| (s, s.points.iter().copied().filter(keep).collect())).collect();
    let all = || series.iter().flat_map(|(_, pts)| pts.iter());
    let (Some(xr), Some(yr)) = (min_max(all().map(|p| p.0)), min_max(all().map(|p| p.1))) else {
        let what = if p.log_y { "no finite point with y > 0 (log y axis)" } else { "no finite point" };
        return Err(PlotError::Empty { path: path.to_owned(), what: what.into() });
    };
    let font = font::font();
    let text = font.is_some();
    render(path, PLOT_SIZE, font, |root| draw_xy_plot(root, p, &series, xr, yr, text))
}

// ---------------------------------------------------------------------------------------------

/// Drawing errors of any backend, flattened to text (the backend types are generic).
struct DrawErr(String);

impl<E: std::error::Error + Send + Sync> From<DrawingAreaErrorKind<E>> for DrawErr {
    fn from(e: DrawingAreaErrorKind<E>) -> Self {
        DrawErr(e.to_string())
    }
}

/// Axis ranges from the data ranges `xr`, `yr` (min, max), then the plot.
fn draw_xy_plot(
    root: &Area,
    p: &XyPlot,
    series: &[(&Series, Vec<(f64, f64)>)],
    xr: (f64, f64),
    yr: (f64, f64),
    text: bool,
) -> std::result::Result<(), DrawErr> {
    let xr = padded(xr);
    if p.log_y {
        // The same 5% margin, in log space; our own ticks (see `ticks::log_key_points`).
        let (lo, hi) = padded((yr.0.log10(), yr.1.log10()));
        let (lo, hi) = (10f64.powf(lo), 10f64.powf(hi));
        let y = (lo..hi).log_scale().with_key_points(ticks::log_key_points(lo, hi));
        draw_xy(root, p, series, xr, y, true, text)
    } else {
        let yr = padded(yr);
        draw_xy(root, p, series, xr, yr.0..yr.1, false, text)
    }
}

type Area<'a> = DrawingArea<canvas::Canvas<'a>, Shift>;

/// Draws into a white RGB buffer, then encodes and writes it (one write, after all drawing).
fn render(
    path: &Path,
    (w, h): (u32, u32),
    font: Option<&'static FontRef<'static>>,
    draw: impl FnOnce(&Area) -> std::result::Result<(), DrawErr>,
) -> Result<()> {
    let mut buf = vec![255u8; w as usize * h as usize * 3];
    {
        let bitmap = BitMapBackend::with_buffer(&mut buf, (w, h));
        let root = canvas::Canvas::new(bitmap, font).into_drawing_area();
        let drawn = draw(&root).and_then(|()| root.present().map_err(DrawErr::from));
        drawn.map_err(|DrawErr(msg)| PlotError::Draw { path: path.to_owned(), msg })?;
    }
    let mut png = Vec::new();
    image::ImageEncoder::write_image(
        image::codecs::png::PngEncoder::new(&mut png),
        &buf,
        w,
        h,
        image::ExtendedColorType::Rgb8,
    )
    .map_err(|source| PlotError::Encode { path: path.to_owned(), source })?;
    std::fs::write(path, png).map_err(|source| PlotError::Write { path: path.to_owned(), source })
}

const TITLE_PX: u32 = 24;
const LABEL_PX: u32 = 16;
const DESC_PX: u32 = 18;
const N_TICKS: usize = 8;
const NAN_COLOR: RGBColor = RGBColor(205, 205, 205);

/// Cell edges of a heatmap, checked against its values.
struct Grid<'v> {
    x_edges: Vec<f64>,
    y_edges: Vec<f64>,
    values: &'v [f64],
}

impl<'v> Grid<'v> {
    fn new(path: &Path, h: &'v Heatmap) -> Result<Self> {
        let err = |what: String| PlotError::Invalid { path: path.to_owned(), what };
        if h.x.is_empty() || h.y.is_empty() {
            return Err(PlotError::Empty {
                path: path.to_owned(),
                what: format!("heatmap has {} x and {} y cell centres", h.x.len(), h.y.len()),
            });
        }
        if h.values.len() != h.x.len() * h.y.len() {
            return Err(err(format!("heatmap has {} values for {} x {} cells", h.values.len(), h.x.len(), h.y.len())));
        }
        let x_edges = edges(&h.x).ok_or_else(|| err("x centres not finite and increasing".into()))?;
        let y_edges = edges(&h.y).ok_or_else(|| err("y centres not finite and increasing".into()))?;
        Ok(Grid { x_edges, y_edges, values: &h.values })
    }

    fn finite_range(&self) -> Option<(f64, f64)> {
        min_max(self.values.iter().copied().filter(|v| v.is_finite()))
    }

    fn data_range(&self, path: &Path) -> Result<(f64, f64)> {
        union_range(path, &[self])
    }
}

fn union_range(path: &Path, grids: &[&Grid]) -> Result<(f64, f64)> {
    let r =
        grids.iter().filter_map(|g| g.finite_range()).reduce(|a, b| (a.0.min(b.0), a.1.max(b.1))).ok_or_else(|| {
            PlotError::Empty {
                path: path.to_owned(),
                what: "heatmap has no finite value (all cells empty) and no colour range".into(),
            }
        })?;
    Ok(widen(r))
}

fn checked_range(path: &Path, (lo, hi): (f64, f64)) -> Result<(f64, f64)> {
    if lo.is_finite() && hi.is_finite() && lo <= hi {
        Ok(widen((lo, hi)))
    } else {
        Err(PlotError::Invalid {
            path: path.to_owned(),
            what: format!("colour range {lo}..{hi} is not finite and increasing"),
        })
    }
}

/// A constant map still needs a non-empty scale to map colours and place ticks.
fn widen((lo, hi): (f64, f64)) -> (f64, f64) {
    if hi > lo {
        (lo, hi)
    } else {
        let half = if lo == 0.0 { 0.5 } else { lo.abs() * 0.05 };
        (lo - half, hi + half)
    }
}

/// Edges of cells centred on `c`: midpoints between neighbours, the outer ones mirrored.
fn edges(c: &[f64]) -> Option<Vec<f64>> {
    if c.iter().any(|v| !v.is_finite()) || c.windows(2).any(|w| w[1] <= w[0]) {
        return None;
    }
    let n = c.len();
    if n == 1 {
        // A single cell has no spacing to go by: give it unit width.
        return Some(vec![c[0] - 0.5, c[0] + 0.5]);
    }
    let mut e = Vec::with_capacity(n + 1);
    e.push(c[0] - (c[1] - c[0]) / 2.0);
    e.extend(c.windows(2).map(|w| (w[0] + w[1]) / 2.0));
    e.push(c[n - 1] + (c[n - 1] - c[n - 2]) / 2.0);
    Some(e)
}

fn min_max(it: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    it.fold(None, |acc, v| match acc {
        None => Some((v, v)),
        Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
    })
}

/// 5% margin each side so that points on the extremes are not drawn on the frame.
fn padded((lo, hi): (f64, f64)) -> (f64, f64) {
    let (lo, hi) = widen((lo, hi));
    let m = (hi - lo) * 0.05;
    (lo - m, hi + m)
}

fn font_style(px: u32) -> TextStyle<'static> {
    ("sans-serif", px).into_font().color(&BLACK)
}

fn draw_heatmap(
    area: &Area,
    h: &Heatmap,
    g: &Grid,
    (lo, hi): (f64, f64),
    text: bool,
) -> std::result::Result<(), DrawErr> {
    // Title above both the map and the bar, so that their plotting areas share top and bottom.
    let body = if text && !h.title.is_empty() {
        area.titled(h.title, font_style(TITLE_PX))?
    } else {
        area.margin(10, 0, 0, 0)
    };
    let bar_w = if text { 125 } else { 45 };
    let (map_area, bar_area) = body.split_horizontally(body.dim_in_pixel().0 - bar_w);

    let (x0, x1) = (g.x_edges[0], *g.x_edges.last().unwrap());
    let (y0, y1) = (g.y_edges[0], *g.y_edges.last().unwrap());
    let bottom = if text { 55 } else { 10 };
    let mut chart = ChartBuilder::on(&map_area)
        .margin(10)
        .x_label_area_size(bottom)
        .y_label_area_size(if text { 75 } else { 10 })
        .build_cartesian_2d(x0..x1, y0..y1)?;

    let nx = g.x_edges.len() - 1;
    let color = |v: f64| {
        if v.is_finite() {
            viridis((v - lo) / (hi - lo))
        } else {
            NAN_COLOR
        }
    };
    chart.draw_series(g.values.iter().enumerate().map(|(k, &v)| {
        let (ix, iy) = (k % nx, k / nx);
        Rectangle::new([(g.x_edges[ix], g.y_edges[iy]), (g.x_edges[ix + 1], g.y_edges[iy + 1])], color(v).filled())
    }))?;
    let (fx, fy) = (ticks::linear(x0, x1, N_TICKS), ticks::linear(y0, y1, N_TICKS));
    let mut mesh = chart.configure_mesh();
    // Grid lines would hide the cells; keep axes and tick marks only.
    mesh.disable_mesh();
    if text {
        mesh.x_labels(N_TICKS)
            .y_labels(N_TICKS)
            .x_label_formatter(&fx)
            .y_label_formatter(&fy)
            .label_style(font_style(LABEL_PX))
            .axis_desc_style(font_style(DESC_PX))
            .x_desc(h.x_label)
            .y_desc(h.y_label);
    } else {
        mesh.disable_axes();
    }
    mesh.draw()?;

    // Colour bar: a 0..1 by lo..hi chart filled with thin bands, ticks on its right side.
    let mut bar = ChartBuilder::on(&bar_area)
        .margin_top(10)
        .margin_bottom(10)
        .margin_right(if text { 15 } else { 20 })
        .x_label_area_size(bottom)
        .right_y_label_area_size(if text { 85 } else { 0 })
        .build_cartesian_2d(0.0..1.0, lo..hi)?;
    const BANDS: usize = 256;
    let step = (hi - lo) / BANDS as f64;
    bar.draw_series((0..BANDS).map(|i| {
        let v = lo + i as f64 * step;
        Rectangle::new([(0.0, v), (1.0, v + step)], color(v + step / 2.0).filled())
    }))?;
    bar.plotting_area().draw(&Rectangle::new([(0.0, lo), (1.0, hi)], BLACK.stroke_width(1)))?;
    let fb = ticks::linear(lo, hi, N_TICKS);
    let mut mesh = bar.configure_mesh();
    mesh.disable_mesh().disable_x_axis().x_labels(0);
    // plotters puts right-side labels twice the tick length away: the default nearly touches.
    mesh.set_tick_mark_size(LabelAreaPosition::Right, 6);
    if text {
        mesh.y_labels(N_TICKS)
            .y_label_formatter(&fb)
            .label_style(font_style(LABEL_PX))
            .axis_desc_style(font_style(DESC_PX))
            .y_desc(h.colorbar_label);
    } else {
        mesh.y_labels(0);
    }
    mesh.draw()?;
    Ok(())
}

/// Matplotlib's tab10: distinct, colour-blind-friendlier than primaries.
const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

fn draw_xy<Y>(
    area: &Area,
    p: &XyPlot,
    series: &[(&Series, Vec<(f64, f64)>)],
    (x0, x1): (f64, f64),
    y_range: Y,
    log_y: bool,
    text: bool,
) -> std::result::Result<(), DrawErr>
where
    Y: AsRangedCoord<Value = f64>,
    Y::CoordDescType: ValueFormatter<f64>,
{
    let mut builder = ChartBuilder::on(area);
    builder.margin(15).x_label_area_size(if text { 55 } else { 10 }).y_label_area_size(if text { 85 } else { 10 });
    if text && !p.title.is_empty() {
        builder.caption(p.title, font_style(TITLE_PX));
    }
    let mut chart = builder.build_cartesian_2d(x0..x1, y_range)?;
    let y_span = chart.y_range();
    let fx = ticks::linear(x0, x1, N_TICKS);
    let fy: Box<dyn Fn(&f64) -> String> =
        if log_y { Box::new(ticks::log) } else { Box::new(ticks::linear(y_span.start, y_span.end, N_TICKS)) };
    let mut mesh = chart.configure_mesh();
    mesh.light_line_style(WHITE);
    if text {
        mesh.x_labels(N_TICKS)
            .y_labels(N_TICKS)
            .x_label_formatter(&fx)
            .y_label_formatter(&fy)
            .label_style(font_style(LABEL_PX))
            .axis_desc_style(font_style(DESC_PX))
            .x_desc(p.x_label)
            .y_desc(p.y_label);
    } else {
        // Even with no labels asked for, log axes still make tick labels: no axes at all,
        // only the grid, and a frame drawn below.
        mesh.disable_axes();
    }
    mesh.draw()?;
    if !text {
        let (xr, yr) = (chart.x_range(), chart.y_range());
        chart.plotting_area().draw(&Rectangle::new([(xr.start, yr.start), (xr.end, yr.end)], BLACK.stroke_width(1)))?;
    }

    for (i, (s, pts)) in series.iter().enumerate() {
        let c = PALETTE[i % PALETTE.len()];
        let line = matches!(s.style, SeriesStyle::Line | SeriesStyle::LinePoints);
        let dots = matches!(s.style, SeriesStyle::Points | SeriesStyle::LinePoints);
        // One legend entry per series, attached to whichever element is drawn first.
        let anno = if line {
            chart.draw_series(LineSeries::new(pts.iter().copied(), c.stroke_width(2)))?
        } else {
            chart.draw_series(pts.iter().map(|&q| Circle::new(q, 3, c.filled())))?
        };
        if text && !s.label.is_empty() {
            // A line sample and/or a dot, as the series is drawn (zero length/radius = none).
            let half = if line { 10 } else { 0 };
            anno.label(s.label).legend(move |(x, y)| {
                EmptyElement::at((x + 10, y))
                    + PathElement::new([(-half, 0), (half, 0)], c.stroke_width(2))
                    + Circle::new((0, 0), if dots { 3 } else { 0 }, c.filled())
            });
        }
        if line && dots {
            chart.draw_series(pts.iter().map(|&q| Circle::new(q, 3, c.filled())))?;
        }
    }
    if text && series.len() > 1 && series.iter().any(|(s, _)| !s.label.is_empty()) {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .label_font(font_style(LABEL_PX))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()?;
    }
    Ok(())
}

/// Viridis (matplotlib) sampled at 9 stops, linearly interpolated; `t` is clamped to 0..1.
fn viridis(t: f64) -> RGBColor {
    const STOPS: [(u8, u8, u8); 9] = [
        (0x44, 0x01, 0x54),
        (0x47, 0x2c, 0x7a),
        (0x3b, 0x51, 0x8b),
        (0x2c, 0x71, 0x8e),
        (0x21, 0x90, 0x8d),
        (0x27, 0xad, 0x81),
        (0x5c, 0xc8, 0x63),
        (0xaa, 0xdc, 0x32),
        (0xfd, 0xe7, 0x25),
    ];
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
    let s = t * (STOPS.len() - 1) as f64;
    let i = (s.floor() as usize).min(STOPS.len() - 2);
    let f = s - i as f64;
    let (a, b) = (STOPS[i], STOPS[i + 1]);
    let mix = |a: u8, b: u8| (a as f64 + (b as f64 - a as f64) * f).round() as u8;
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

#[cfg(test)]
mod tests {
    //! Render without a font (as on a machine with none): the no-text layout must draw and
    //! write; these tests never load the font.
    use super::*;

    fn sample() -> Heatmap<'static> {
        let (x, y, values) =
            grid_cells(&[(0.0, 0.0, 1.0), (3.0, 0.0, 2.0), (0.0, 3.0, f64::NAN), (3.0, 3.0, 4.0)], 3.0, Reduce::Mean);
        Heatmap { title: "t", x_label: "x", y_label: "y", colorbar_label: "c", x, y, values, range: None }
    }

    #[test]
    fn plots_without_a_font_have_no_text_but_are_written() {
        let dir = tempfile::tempdir().unwrap();
        let h = sample();
        let g = Grid::new(dir.path(), &h).unwrap();
        let r = g.data_range(dir.path()).unwrap();
        let path = dir.path().join("nofont.png");
        render(&path, PLOT_SIZE, None, |root| draw_heatmap(root, &h, &g, r, false)).unwrap();
        assert!(std::fs::metadata(&path).unwrap().len() > 100);

        let p = XyPlot {
            title: "t",
            x_label: "x",
            y_label: "y",
            series: vec![
                Series { label: "a", points: vec![(1.0, 1.0), (2.0, 0.1)], style: SeriesStyle::Line },
                Series { label: "b", points: vec![(1.0, 2.0), (2.0, 0.2)], style: SeriesStyle::Points },
            ],
            log_y: true,
        };
        let s: Vec<_> = p.series.iter().map(|s| (s, s.points.clone())).collect();
        let path = dir.path().join("nofont_xy.png");
        render(&path, PLOT_SIZE, None, |root| draw_xy_plot(root, &p, &s, (1.0, 2.0), (0.1, 2.0), false)).unwrap();
        assert!(std::fs::metadata(&path).unwrap().len() > 100);
    }

    #[test]
    fn viridis_ends_and_clamps() {
        assert_eq!(viridis(0.0), RGBColor(0x44, 0x01, 0x54));
        assert_eq!(viridis(1.0), RGBColor(0xfd, 0xe7, 0x25));
        assert_eq!(viridis(-3.0), viridis(0.0));
        assert_eq!(viridis(7.0), viridis(1.0));
    }

    #[test]
    fn edges_are_midpoints() {
        assert_eq!(edges(&[0.0, 2.0, 4.0]).unwrap(), vec![-1.0, 1.0, 3.0, 5.0]);
        assert_eq!(edges(&[5.0]).unwrap(), vec![4.5, 5.5]);
        assert!(edges(&[1.0, 1.0]).is_none());
        assert!(edges(&[0.0, f64::NAN]).is_none());
    }
}
