//! `abvs disparity-eval`: disparity engines scored against a ground-truth map (PFM, or PNG with a scale),
//! printed as a table or JSON, with the bad-2 against density curves as PNG. The scoring (what each mode
//! scores, EPE, bad-k, density, timing): `abvs_disparity::eval`. `--resolution WxH` first resamples the pair
//! (and the ground truth, scaled by the horizontal factor) to the runtime's size.
use std::path::PathBuf;
use std::process::ExitCode;

use abvs_disparity::engine::set_opencv_threads;
use abvs_disparity::estimate::read_gray;
use abvs_disparity::eval::{eval_at_model_resolution, eval_native, EvalRow, EvalSpec, NativeEval};
use abvs_disparity::manifest::default_models;
use abvs_disparity::resample::resize_mat;
use clap::Args;
use opencv::core::Mat;
use opencv::prelude::*;

#[derive(Args)]
pub struct EvalArgs {
    /// Left rectified image.
    #[arg(long)]
    left: PathBuf,
    /// Right rectified image, the same size as the left.
    #[arg(long)]
    right: PathBuf,
    /// Ground truth: PFM (pixels, inf/NaN/0 = unknown) or an 8/16-bit PNG divided by --gt-scale (0 = unknown).
    #[arg(long)]
    gt: PathBuf,
    /// Divisor of a PNG ground truth's values (pixels = value / scale; up to 1e6).
    #[arg(long, default_value_t = 1.0, value_parser = crate::args::positive_up_to(1e6))]
    gt_scale: f64,
    /// Model directories or .onnx files to score (default: the shipped variants).
    #[arg(long)]
    model: Vec<PathBuf>,
    /// Timed runs per engine (median reported).
    #[arg(long, default_value_t = 20, value_parser = crate::args::count(1usize, 10_000))]
    runs: usize,
    /// Threads of the ONNX engine (1 to 256).
    #[arg(long, default_value_t = 2, value_parser = crate::args::count(1usize, 256))]
    threads: usize,
    /// Print JSON instead of the table.
    #[arg(long)]
    json: bool,
    /// Score each model at its own resolution against SGBM at the same one (the networks' training
    /// protocol) instead of what `abvs disparity` gives at the input's resolution.
    #[arg(long)]
    at_model_resolution: bool,
    /// The default (kept for scripts): score at the input's own resolution (the ground truth's): the default
    /// `abvs disparity` engine (fused), each shipped network (resampled to the input), and SGBM at the input
    /// resolution with OpenCV's usual settings for the ground truth's disparity range, plus the left-right
    /// check's effect (density and bad-2 kept) for the default engine.
    #[arg(long, hide = true, conflicts_with = "at_model_resolution")]
    native: bool,
    /// bad-2 against density (pixels kept by confidence) as PNG, for the default engine and the network
    /// alone (not with --at-model-resolution).
    #[arg(long, conflicts_with = "at_model_resolution")]
    curve: Option<PathBuf>,
    /// Resample the pair to WxH first (INTER_AREA; the ground truth nearest-neighbour, its values scaled by
    /// the horizontal factor) and score there: e.g. 640x480, the runtime's resolution.
    #[arg(long, conflicts_with = "at_model_resolution", value_parser = parse_size)]
    resolution: Option<(u32, u32)>,
    /// Score the runtime's fovea (issue 38) instead: a WxH window at the pair's centre, matched at the
    /// pair's own scale around the runtime's main map (census-refine at 640 px wide, its validity mask,
    /// upsampled), against that main map over the same pixels (end-point error and bad-1 where both answer;
    /// each one's density of the ground-truth pixels). E.g. 320x240, the runtime's default window.
    #[arg(long, value_parser = parse_size, conflicts_with_all = ["at_model_resolution", "resolution", "curve"])]
    fovea: Option<(u32, u32)>,
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let bad = || format!("`{s}` is not WxH (e.g. 640x480)");
    let (w, h) = s.split_once('x').ok_or_else(bad)?;
    let (w, h): (u32, u32) = (w.parse().map_err(|_| bad())?, h.parse().map_err(|_| bad())?);
    if w < 16 || h < 16 || w > 8192 || h > 8192 {
        return Err(format!("{s}: each side must be in 16..=8192"));
    }
    Ok((w, h))
}

pub fn run_eval(a: EvalArgs) -> anyhow::Result<ExitCode> {
    let (mut l, mut r) = (read_gray(&a.left)?, read_gray(&a.right)?);
    if let Some((w, h)) = a.resolution {
        let to = |m: &Mat| -> anyhow::Result<Mat> {
            let v = resize_mat(m, w as i32, h as i32)?;
            Ok(Mat::new_rows_cols_with_data(h as i32, w as i32, &v)?.try_clone()?)
        };
        (l, r) = (to(&l)?, to(&r)?);
    }
    set_opencv_threads(a.threads)?;
    if let Some(win) = a.fovea {
        let (_, _, gt) = abvs_disparity::score::load_gt(&a.gt, a.gt_scale, l.cols() as u32, l.rows() as u32)?;
        let e = abvs_disparity::fovea_eval::eval_fovea(&l, &r, &gt, win, a.threads)?;
        return print_fovea(&e, a.json);
    }
    let spec = EvalSpec {
        gt: a.gt.clone(),
        gt_scale: a.gt_scale,
        models: if a.model.is_empty() { default_models() } else { a.model.clone() },
        runs: a.runs,
        threads: a.threads,
    };
    if a.at_model_resolution {
        return print_rows(&eval_at_model_resolution(&l, &r, &spec)?, a.json);
    }
    let e = eval_native(&l, &r, &spec)?;
    if let Some(p) = &a.curve {
        plot_curves(p, &e)?;
    }
    print_rows(&e.rows, a.json)
}

fn print_rows(rows: &[EvalRow], json: bool) -> anyhow::Result<ExitCode> {
    if json {
        // through a JSON value: its keys in order, as the rows were always written
        println!("{}", serde_json::to_string_pretty(&serde_json::to_value(rows)?)?);
    } else {
        println!(
            "{:<18} {:>9} {:>8} {:>8} {:>8} {:>8} {:>7} {:>9} {:>8} {:>11}",
            "engine", "res", "EPE px", "bad-1 %", "bad-2 %", "bad-3 %", "valid", "ms", "density", "bad-2 valid"
        );
        for s in rows {
            let p = s.published.map_or((f64::NAN, f64::NAN), |p| (p.density, p.bad2_pct_of_valid));
            println!(
                "{:<18} {:>9} {:>8.3} {:>8.2} {:>8.2} {:>8.2} {:>7.3} {:>9.2} {:>8.3} {:>11.2}",
                s.engine,
                s.resolution,
                s.epe_px,
                s.bad1_pct,
                s.bad2_pct,
                s.bad3_pct,
                s.valid_fraction,
                s.ms_median,
                p.0,
                p.1
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// bad-2 against density: a line per engine with a confidence, SGBM's published pixels as one point.
fn print_fovea(e: &abvs_disparity::fovea_eval::FoveaEval, json: bool) -> anyhow::Result<ExitCode> {
    if json {
        println!("{}", serde_json::to_string_pretty(e)?);
        return Ok(ExitCode::SUCCESS);
    }
    let [x0, y0, w, h] = e.window;
    println!(
        "fovea {w}x{h} at ({x0}, {y0}) of {}x{}; main map {} at {}x{} (validity mask {}), upsampled",
        e.size[0], e.size[1], e.engine, e.main_resolution[0], e.main_resolution[1], e.min_confidence
    );
    println!(
        "search [{}, {}) px{}; {} ground-truth pixels, {} answered by both",
        e.search_px[0],
        e.search_px[1],
        if e.from_main { "" } else { " (not from the main map)" },
        e.gt_pixels,
        e.common_pixels
    );
    println!("{:<16} {:>8} {:>8} {:>8}", "map", "density", "EPE px", "bad-1 %");
    for (name, s) in [("main, upsampled", &e.main), ("fovea", &e.fovea)] {
        println!("{name:<16} {:>8.3} {:>8.3} {:>8.2}", s.density, s.epe_px, s.bad1_pct);
    }
    println!(
        "EPE fovea / main: {:.3}; the main map filled {}, overruled {}, masked {} fovea pixels",
        e.epe_ratio, e.filled_from_main, e.overruled_by_main, e.masked_by_main
    );
    Ok(ExitCode::SUCCESS)
}

fn plot_curves(p: &std::path::Path, e: &NativeEval) -> anyhow::Result<()> {
    let sgbm_name = e.rows.last().map_or("sgbm", |r| r.engine.as_str());
    let sgbm_label = format!("{sgbm_name} (its own checks)");
    let mut series: Vec<abvs_plot::Series> = e
        .curves
        .iter()
        .map(|(name, c)| abvs_plot::Series {
            label: name,
            points: c.iter().map(|(dn, b)| (100.0 * dn, *b)).collect(),
            style: abvs_plot::SeriesStyle::Line,
        })
        .collect();
    series.push(abvs_plot::Series {
        label: &sgbm_label,
        points: vec![(100.0 * e.sgbm_published.0, e.sgbm_published.1)],
        style: abvs_plot::SeriesStyle::Points,
    });
    abvs_plot::xy_plot(
        p,
        &abvs_plot::XyPlot {
            title: "bad-2 of the pixels kept by confidence (left-right check; census-refine's own)",
            x_label: "density (% of ground-truth pixels kept)",
            y_label: "bad-2 (%)",
            series,
            log_y: false,
        },
    )?;
    Ok(())
}
