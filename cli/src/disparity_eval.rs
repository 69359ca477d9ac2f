//! `abvs disparity-eval`: disparity engines scored against a ground-truth map (PFM, or PNG with a scale).
//!
//! EPE over the pixels an engine answers, bad-1/2/3 as % of valid ground-truth pixels (a pixel without an
//! estimate counts as bad), and each engine's time (median of repeated runs). By default it scores what
//! `abvs disparity` gives at the input's resolution (the default engine, the runtime's default engine
//! census-refine, each network, SGBM_3WAY with the ground truth's range, all with the same threads), with
//! the left-right check's density and the bad-2 against density curve; `--resolution WxH` first resamples
//! the pair (and the ground truth, scaled by the horizontal factor) to the runtime's size;
//! `--at-model-resolution` scores every model at its own resolution against SGBM at the same one.
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use abvs_disparity::census::CensusRefineEngine;
use abvs_disparity::confidence::mask;
use abvs_disparity::engine::{compute, set_opencv_threads, DisparityEngine};
use abvs_disparity::estimate::{estimate, read_gray};
use abvs_disparity::fused::FusedEngine;
use abvs_disparity::manifest::{default_model_for, default_models, refine_base};
use abvs_disparity::onnx::OnnxEngine;
use abvs_disparity::resample::{resize_mat, upsample_disparity};
use abvs_disparity::score::{bad2_at, density_at, density_curve, load_gt, mask_curve, published_score};
use abvs_disparity::sgbm::SgbmEngine;
use abvs_runtime_core::config::EngineKind;
use abvs_runtime_core::params::DEFAULT_MIN_CONFIDENCE;
use anyhow::{bail, Context};
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

/// EPE over pixels with both values; bad-k over valid ground truth (no estimate = bad).
fn score(d: &[f32], gt: &[f32], max_disp: f64) -> serde_json::Value {
    let s = abvs_sim::disparity_score::score_disparity(d, gt, max_disp);
    serde_json::json!({ "epe_px": s.epe_px, "bad1_pct": s.bad_pct[0], "bad2_pct": s.bad_pct[1],
        "bad3_pct": s.bad_pct[2], "valid_fraction": s.valid_fraction, "gt_pixels": s.gt_pixels })
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
        let (_, _, gt) = load_gt(&a.gt, a.gt_scale, l.cols() as u32, l.rows() as u32)?;
        let e = abvs_disparity::fovea_eval::eval_fovea(&l, &r, &gt, win, a.threads)?;
        return print_fovea(&e, a.json);
    }
    if !a.at_model_resolution {
        let rows = run_native(&a, &l, &r)?;
        return print_rows(&rows, a.json);
    }
    let models = if a.model.is_empty() { default_models() } else { a.model.clone() };
    if models.is_empty() {
        bail!("no disparity model given and none shipped under models/hitnet/");
    }
    let mut rows = Vec::new();
    for m in &models {
        let onnx = OnnxEngine::load(m, a.threads)?;
        let (w, h, max) = (onnx.manifest.width, onnx.manifest.height, onnx.manifest.max_disparity);
        let (lv, rv) = (resize_mat(&l, w as i32, h as i32)?, resize_mat(&r, w as i32, h as i32)?);
        let (_, _, gt) = load_gt(&a.gt, a.gt_scale, w, h)?;
        let beyond = gt.iter().filter(|g| g.is_finite() && (**g as f64) >= max).count();
        let engines: Vec<Box<dyn DisparityEngine>> = vec![Box::new(onnx), Box::new(SgbmEngine::new(w, h, max)?)];
        for mut e in engines {
            let d = compute(e.as_mut(), &lv, &rv)?;
            let mut times = Vec::with_capacity(a.runs);
            let mut buf = d.clone();
            for _ in 0..a.runs.max(1) {
                let t = Instant::now();
                e.compute(&lv, &rv, &mut buf)?;
                times.push(t.elapsed().as_secs_f64() * 1e3);
            }
            times.sort_by(f64::total_cmp);
            let mut s = score(&d, &gt, max);
            s["engine"] = serde_json::json!(e.name());
            s["resolution"] = serde_json::json!(format!("{w}x{h}"));
            s["max_disparity"] = serde_json::json!(max);
            s["gt_pixels_beyond_max_disparity"] = serde_json::json!(beyond);
            s["ms_median"] = serde_json::json!(times[times.len() / 2]);
            rows.push(s);
        }
    }
    print_rows(&rows, a.json)
}

fn print_rows(rows: &[serde_json::Value], json: bool) -> anyhow::Result<ExitCode> {
    if json {
        println!("{}", serde_json::to_string_pretty(rows)?);
    } else {
        println!(
            "{:<18} {:>9} {:>8} {:>8} {:>8} {:>8} {:>7} {:>9} {:>8} {:>11}",
            "engine", "res", "EPE px", "bad-1 %", "bad-2 %", "bad-3 %", "valid", "ms", "density", "bad-2 valid"
        );
        for s in rows {
            println!(
                "{:<18} {:>9} {:>8.3} {:>8.2} {:>8.2} {:>8.2} {:>7.3} {:>9.2} {:>8.3} {:>11.2}",
                s["engine"].as_str().unwrap_or(""),
                s["resolution"].as_str().unwrap_or(""),
                s["epe_px"].as_f64().unwrap_or(f64::NAN),
                s["bad1_pct"].as_f64().unwrap_or(f64::NAN),
                s["bad2_pct"].as_f64().unwrap_or(f64::NAN),
                s["bad3_pct"].as_f64().unwrap_or(f64::NAN),
                s["valid_fraction"].as_f64().unwrap_or(f64::NAN),
                s["ms_median"].as_f64().unwrap_or(f64::NAN),
                s["published"]["density"].as_f64().unwrap_or(f64::NAN),
                s["published"]["bad2_pct_of_valid"].as_f64().unwrap_or(f64::NAN)
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}

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

/// Median of `runs` timed calls (ms).
fn median_ms(runs: usize, mut f: impl FnMut() -> anyhow::Result<()>) -> anyhow::Result<f64> {
    let mut t = Vec::with_capacity(runs.max(1));
    for _ in 0..runs.max(1) {
        let s = Instant::now();
        f()?;
        t.push(s.elapsed().as_secs_f64() * 1e3);
    }
    t.sort_by(f64::total_cmp);
    Ok(t[t.len() / 2])
}

/// The engines at the input's resolution (the default mode).
fn run_native(a: &EvalArgs, l: &Mat, r: &Mat) -> anyhow::Result<Vec<serde_json::Value>> {
    let (iw, ih) = (l.cols() as u32, l.rows() as u32);
    let (_, _, gt) = load_gt(&a.gt, a.gt_scale, iw, ih)?;
    let gt_max = gt.iter().filter(|g| g.is_finite()).fold(0f32, |m, g| m.max(*g)) as f64;
    if gt_max <= 0.0 {
        bail!("{}: no known ground-truth disparity", a.gt.display());
    }
    // nothing is beyond the range here: SGBM searches the ground truth's whole range
    let max = f64::INFINITY;
    let (lb, rb) = (l.data_bytes()?.to_vec(), r.data_bytes()?.to_vec());
    let mut rows = Vec::new();
    let mut curves = Vec::new();
    // SGBM as users run it: SGBM_3WAY at the input resolution, the ground truth's range (first: its density
    // is where the others' curves are read)
    let mut sgbm = SgbmEngine::new(iw, ih, gt_max + 1.0)?;
    let sgbm_d = compute(&mut sgbm, &lb, &rb)?;
    let (sgbm_density, sgbm_bad) = published_score(&sgbm_d, &gt, max);
    let default_model = default_model_for(iw, ih);
    let mut nets: Vec<PathBuf> = if a.model.is_empty() { default_models() } else { a.model.clone() };
    nets.retain(|m| m != &default_model);
    let mut cases = vec![
        (EngineKind::Fused, default_model.clone(), true),
        (EngineKind::CensusRefine, default_model.clone(), false),
        (EngineKind::Onnx, default_model, true),
    ];
    // every other network alone and refined, so a cheaper base for census-refine is measured too
    cases.extend(
        nets.into_iter().flat_map(|m| [(EngineKind::CensusRefine, m.clone(), false), (EngineKind::Onnx, m, false)]),
    );
    for (kind, model, default) in cases {
        let est = estimate(l, r, kind.as_str(), &model, a.threads, None)?;
        let mut s = score(&est.disparity, &gt, max);
        // what is published: the validity mask at its default where the engine scores its pixels
        let mut published = est.disparity.clone();
        if let Some((conf, why)) = &est.own {
            let min = DEFAULT_MIN_CONFIDENCE;
            mask(conf, min, &mut published, &mut why.clone());
            let curve = density_curve(&est.disparity, conf, &gt, max);
            let ts: Vec<f32> = (0..=20).map(|i| i as f32 * 0.05).collect();
            s["own_confidence"] = serde_json::json!({
                "min_confidence": min,
                "bad2_pct_of_valid_at_sgbm_density": bad2_at(&curve, sgbm_density),
                "density_at_sgbm_bad2": density_at(&curve, sgbm_bad),
                "mask_curve": mask_curve(&est.disparity, conf, &gt, max, &ts),
            });
            curves.push((format!("{} (own confidence)", est.engine), curve));
        }
        let (dn, b) = published_score(&published, &gt, max);
        s["published"] = serde_json::json!({ "density": dn, "bad2_pct_of_valid": b });
        // time: the engine on the pair, resizing and resampling included, model loading not
        let ms = {
            let net = if kind == EngineKind::CensusRefine { refine_base(&model)? } else { model.clone() };
            let onnx = OnnxEngine::load(&net, a.threads)?;
            let (mw, mh) = onnx.size();
            if kind == EngineKind::Fused {
                let mut e = FusedEngine::new(onnx, iw, ih)?;
                let mut out = vec![0f32; (iw * ih) as usize];
                median_ms(a.runs, || Ok(e.compute(&lb, &rb, &mut out)?))?
            } else if kind == EngineKind::CensusRefine {
                let mut e = CensusRefineEngine::new(onnx, iw, ih)?;
                let mut out = vec![0f32; (iw * ih) as usize];
                median_ms(a.runs, || Ok(e.compute(&lb, &rb, &mut out)?))?
            } else {
                let mut e = onnx;
                let mut up = vec![0f32; (iw * ih) as usize];
                median_ms(a.runs, || {
                    let (lm, rm) = (resize_mat(l, mw as i32, mh as i32)?, resize_mat(r, mw as i32, mh as i32)?);
                    let d = compute(&mut e, &lm, &rm)?;
                    upsample_disparity(&d, (mw as usize, mh as usize), &mut up, (iw as usize, ih as usize));
                    Ok(())
                })?
            }
        };
        if default {
            // the left-right check: what it keeps, and bad-2 against density by confidence
            let chk = estimate(l, r, kind.as_str(), &model, a.threads, Some(1.0))?;
            let (conf, _) = chk.checked.as_ref().context("left-right check")?;
            let kept = score(&chk.disparity, &gt, max);
            let curve = density_curve(&chk.disparity, conf, &gt, max);
            let at = |density: f64| curve.iter().rev().find(|(dn, _)| *dn <= density).map(|(dn, b)| (*dn, *b));
            let full_bad = s["bad2_pct"].as_f64().unwrap_or(f64::NAN);
            // bad-2 counts unanswered pixels as bad: over the kept ones it is (bad - dropped) / kept
            let v = kept["valid_fraction"].as_f64().unwrap_or(0.0);
            let bad_kept = (kept["bad2_pct"].as_f64().unwrap_or(0.0) - 100.0 * (1.0 - v)) / v.max(1e-9);
            s["lr_check"] = serde_json::json!({
                "density": v,
                "bad2_pct_of_kept": bad_kept,
                "at_85pct_density": at(0.85).map(|(dn, b)| serde_json::json!({
                    "density": dn, "bad2_pct_of_kept": b,
                    // share of the full-density bad-2 pixels that the 15 % removed took away
                    "bad2_removed_fraction": 1.0 - b * dn / full_bad,
                })),
            });
            curves.push((est.engine.clone(), curve));
        }
        s["engine"] = serde_json::json!(est.engine);
        s["default"] = serde_json::json!(default && kind == EngineKind::Fused);
        s["runtime_default"] = serde_json::json!(kind == EngineKind::CensusRefine);
        s["resolution"] = serde_json::json!(format!("{iw}x{ih}"));
        s["network_resolution"] = serde_json::json!(format!("{}x{}", est.model_size.0, est.model_size.1));
        s["ms_median"] = serde_json::json!(ms);
        rows.push(s);
    }
    let mut s = score(&sgbm_d, &gt, max);
    s["published"] = serde_json::json!({ "density": sgbm_density, "bad2_pct_of_valid": sgbm_bad });
    let mut buf = sgbm_d.clone();
    s["ms_median"] = serde_json::json!(median_ms(a.runs, || Ok(sgbm.compute(&lb, &rb, &mut buf)?))?);
    s["engine"] = serde_json::json!(format!("sgbm (range {})", sgbm.max_disparity()));
    s["default"] = serde_json::json!(false);
    s["runtime_default"] = serde_json::json!(false);
    s["resolution"] = serde_json::json!(format!("{iw}x{ih}"));
    s["network_resolution"] = serde_json::json!("-");
    rows.push(s);
    if let Some(p) = &a.curve {
        let sgbm_name = rows.last().and_then(|r| r["engine"].as_str()).unwrap_or("sgbm");
        let sgbm_label = format!("{sgbm_name} (its own checks)");
        let mut series: Vec<abvs_plot::Series> = curves
            .iter()
            .map(|(name, c)| abvs_plot::Series {
                label: name,
                points: c.iter().map(|(dn, b)| (100.0 * dn, *b)).collect(),
                style: abvs_plot::SeriesStyle::Line,
            })
            .collect();
        series.push(abvs_plot::Series {
            label: &sgbm_label,
            points: vec![(100.0 * sgbm_density, sgbm_bad)],
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
    }
    Ok(rows)
}
