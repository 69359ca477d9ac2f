//! `abvs disparity` and `abvs disparity-eval`: the runtime's disparity engines on a rectified image pair.
//!
//! Both engines run at the model's resolution (SGBM at the same one, for a like-for-like comparison): inputs
//! are resized to it (INTER_AREA; anisotropic resizes keep rows epipolar) and disparities scaled by the
//! width ratio. `disparity` writes the left-view disparity at the input resolution as PFM (invalid = inf);
//! `disparity-eval` scores both engines against a ground-truth map (PFM, or PNG with a scale), EPE over pixels
//! both have, bad-1/2/3 as % of valid ground-truth pixels (a pixel without an estimate counts as bad), and
//! times each engine (median of repeated runs).
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use abvs_runtime::tasks::disparity::{self, DisparityEngine};
use anyhow::{bail, Context};
use clap::Args;
use opencv::core::{Mat, Size};
use opencv::prelude::*;
use opencv::{imgcodecs, imgproc};

#[derive(Args)]
pub struct DisparityArgs {
    #[arg(long)]
    left: PathBuf,
    #[arg(long)]
    right: PathBuf,
    /// Output PFM (left-view disparity in pixels at the input resolution, invalid = inf).
    #[arg(long)]
    out: PathBuf,
    /// Model directory or .onnx (default: the shipped hitnet-s).
    #[arg(long)]
    model: Option<PathBuf>,
    #[arg(long, default_value = "onnx")]
    engine: String,
    #[arg(long, default_value_t = 2)]
    threads: usize,
}

#[derive(Args)]
pub struct EvalArgs {
    #[arg(long)]
    left: PathBuf,
    #[arg(long)]
    right: PathBuf,
    /// Ground truth: PFM (pixels, inf/NaN/0 = unknown) or an 8/16-bit PNG divided by --gt-scale (0 = unknown).
    #[arg(long)]
    gt: PathBuf,
    #[arg(long, default_value_t = 1.0)]
    gt_scale: f64,
    /// Model directories or .onnx files to score (default: the shipped variants).
    #[arg(long)]
    model: Vec<PathBuf>,
    /// Timed runs per engine (median reported).
    #[arg(long, default_value_t = 20)]
    runs: usize,
    #[arg(long, default_value_t = 2)]
    threads: usize,
    /// Print JSON instead of the table.
    #[arg(long)]
    json: bool,
}

fn gray(path: &Path) -> anyhow::Result<Mat> {
    let m = imgcodecs::imread(path.to_str().context("path is not UTF-8")?, imgcodecs::IMREAD_GRAYSCALE)?;
    if m.empty() {
        bail!("{}: cannot read the image (missing or not an image)", path.display());
    }
    Ok(m)
}

fn resize_to(m: &Mat, w: i32, h: i32) -> anyhow::Result<Vec<u8>> {
    let mut r = Mat::default();
    if m.cols() == w && m.rows() == h {
        r = m.try_clone()?;
    } else {
        imgproc::resize(m, &mut r, Size::new(w, h), 0.0, 0.0, imgproc::INTER_AREA)?;
    }
    Ok(r.data_bytes()?.to_vec())
}

/// Writes a PFM (grayscale, little-endian, rows bottom to top); NaN is written as +inf (the format's "no value").
pub fn write_pfm(path: &Path, w: usize, h: usize, data: &[f32]) -> anyhow::Result<()> {
    let mut out = format!("Pf\n{w} {h}\n-1.0\n").into_bytes();
    out.reserve(w * h * 4);
    for y in (0..h).rev() {
        for v in &data[y * w..(y + 1) * w] {
            let v = if v.is_nan() { f32::INFINITY } else { *v };
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    std::fs::write(path, out).with_context(|| format!("writing {}", path.display()))
}

/// Reads a grayscale PFM into row-major top-to-bottom order.
pub fn read_pfm(path: &Path) -> anyhow::Result<(usize, usize, Vec<f32>)> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let mut fields = Vec::new();
    let mut pos = 0;
    while fields.len() < 4 {
        while pos < bytes.len() && bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        let start = pos;
        while pos < bytes.len() && !bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        if start == pos {
            bail!("{}: truncated PFM header", path.display());
        }
        fields.push(String::from_utf8_lossy(&bytes[start..pos]).into_owned());
    }
    pos += 1;
    if fields[0] != "Pf" {
        bail!("{}: `{}` is not a grayscale PFM (expected Pf)", path.display(), fields[0]);
    }
    let w: usize = fields[1].parse().with_context(|| format!("{}: width", path.display()))?;
    let h: usize = fields[2].parse().with_context(|| format!("{}: height", path.display()))?;
    let scale: f32 = fields[3].parse().with_context(|| format!("{}: scale", path.display()))?;
    if bytes.len() < pos + w * h * 4 {
        bail!("{}: {} bytes of data for {w}x{h}", path.display(), bytes.len().saturating_sub(pos));
    }
    let mut out = vec![0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let o = pos + ((h - 1 - y) * w + x) * 4;
            let b = [bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]];
            out[y * w + x] = if scale < 0.0 { f32::from_le_bytes(b) } else { f32::from_be_bytes(b) };
        }
    }
    Ok((w, h, out))
}

fn default_models() -> Vec<PathBuf> {
    ["hitnet-s", "hitnet-m"]
        .iter()
        .map(|v| crate::run::shipped(&format!("models/hitnet/{v}")))
        .filter(|p| p.join("manifest.json").exists())
        .collect()
}

/// Runs an engine on a pair already at its resolution.
fn compute(e: &mut dyn DisparityEngine, l: &[u8], r: &[u8]) -> anyhow::Result<Vec<f32>> {
    let (w, h) = e.size();
    let mut d = vec![f32::NAN; (w * h) as usize];
    e.compute(l, r, &mut d)?;
    Ok(d)
}

pub fn run_disparity(a: DisparityArgs) -> anyhow::Result<ExitCode> {
    let (l, r) = (gray(&a.left)?, gray(&a.right)?);
    if l.size()? != r.size()? {
        bail!("left {}x{} and right {}x{} differ in size", l.cols(), l.rows(), r.cols(), r.rows());
    }
    let model = a.model.clone().unwrap_or_else(|| crate::run::shipped("models/hitnet/hitnet-s"));
    let onnx = disparity::OnnxEngine::load(&model, a.threads)?;
    let (mw, mh) = (onnx.manifest.width, onnx.manifest.height);
    let max = onnx.manifest.max_disparity;
    let mut engine: Box<dyn DisparityEngine> = match a.engine.as_str() {
        "onnx" => Box::new(onnx),
        "sgbm" => Box::new(disparity::SgbmEngine::new(mw, mh, max)?),
        other => bail!("--engine `{other}`: expected onnx or sgbm"),
    };
    let d = compute(engine.as_mut(), &resize_to(&l, mw as i32, mh as i32)?, &resize_to(&r, mw as i32, mh as i32)?)?;
    // back to the input resolution, values scaled by the width ratio
    let (iw, ih) = (l.cols() as usize, l.rows() as usize);
    let sx = iw as f32 / mw as f32;
    let mut out = vec![f32::NAN; iw * ih];
    for y in 0..ih {
        let yy = (((y as f32 + 0.5) * mh as f32 / ih as f32) as usize).min(mh as usize - 1);
        for x in 0..iw {
            let xx = (((x as f32 + 0.5) / sx) as usize).min(mw as usize - 1);
            out[y * iw + x] = d[yy * mw as usize + xx] * sx;
        }
    }
    write_pfm(&a.out, iw, ih, &out)?;
    let valid = out.iter().filter(|v| v.is_finite()).count();
    eprintln!(
        "wrote {} ({iw}x{ih}, engine {} at {mw}x{mh}, {:.1}% valid)",
        a.out.display(),
        engine.name(),
        100.0 * valid as f64 / out.len() as f64
    );
    Ok(ExitCode::SUCCESS)
}

/// Ground truth at the engine resolution (nearest neighbour, values scaled by the width ratio; NaN unknown).
fn load_gt(path: &Path, scale: f64, w: u32, h: u32) -> anyhow::Result<(usize, usize, Vec<f32>)> {
    let (gw, gh, g) = if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("pfm")) {
        read_pfm(path)?
    } else {
        let m = imgcodecs::imread(path.to_str().context("path is not UTF-8")?, imgcodecs::IMREAD_UNCHANGED)?;
        if m.empty() || m.channels() != 1 {
            bail!("{}: not a single-channel ground-truth image", path.display());
        }
        let mut f = Mat::default();
        m.convert_to(&mut f, opencv::core::CV_32F, 1.0 / scale, 0.0)?;
        let v: Vec<f32> = f.data_typed::<f32>()?.iter().map(|x| if *x > 0.0 { *x } else { f32::NAN }).collect();
        (m.cols() as usize, m.rows() as usize, v)
    };
    let sx = w as f32 / gw as f32;
    let mut out = vec![f32::NAN; (w * h) as usize];
    for y in 0..h as usize {
        let yy = (((y as f32 + 0.5) * gh as f32 / h as f32) as usize).min(gh - 1);
        for x in 0..w as usize {
            let xx = (((x as f32 + 0.5) / sx) as usize).min(gw - 1);
            let v = g[yy * gw + xx];
            out[y * w as usize + x] = if v.is_finite() && v > 0.0 { v * sx } else { f32::NAN };
        }
    }
    Ok((gw, gh, out))
}

/// EPE over pixels with both values; bad-k over valid ground truth (no estimate = bad).
fn score(d: &[f32], gt: &[f32], max_disp: f64) -> serde_json::Value {
    let (mut n, mut both, mut sum, mut bad) = (0usize, 0usize, 0f64, [0usize; 3]);
    for (p, g) in d.iter().zip(gt) {
        if !(g.is_finite() && (*g as f64) < max_disp) {
            continue;
        }
        n += 1;
        if !p.is_finite() {
            bad.iter_mut().for_each(|b| *b += 1);
            continue;
        }
        let e = (p - g).abs() as f64;
        both += 1;
        sum += e;
        for (k, b) in bad.iter_mut().enumerate() {
            if e > (k + 1) as f64 {
                *b += 1;
            }
        }
    }
    let pct = |b: usize| 100.0 * b as f64 / n.max(1) as f64;
    serde_json::json!({ "epe_px": sum / both.max(1) as f64, "bad1_pct": pct(bad[0]), "bad2_pct": pct(bad[1]),
        "bad3_pct": pct(bad[2]), "valid_fraction": both as f64 / n.max(1) as f64, "gt_pixels": n })
}

pub fn run_eval(a: EvalArgs) -> anyhow::Result<ExitCode> {
    let (l, r) = (gray(&a.left)?, gray(&a.right)?);
    let models = if a.model.is_empty() { default_models() } else { a.model.clone() };
    if models.is_empty() {
        bail!("no disparity model given and none shipped under models/hitnet/");
    }
    let mut rows = Vec::new();
    for m in &models {
        let onnx = disparity::OnnxEngine::load(m, a.threads)?;
        let (w, h, max) = (onnx.manifest.width, onnx.manifest.height, onnx.manifest.max_disparity);
        let (lv, rv) = (resize_to(&l, w as i32, h as i32)?, resize_to(&r, w as i32, h as i32)?);
        let (_, _, gt) = load_gt(&a.gt, a.gt_scale, w, h)?;
        let beyond = gt.iter().filter(|g| g.is_finite() && (**g as f64) >= max).count();
        let engines: Vec<Box<dyn DisparityEngine>> =
            vec![Box::new(onnx), Box::new(disparity::SgbmEngine::new(w, h, max)?)];
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
    if a.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    } else {
        println!(
            "{:<18} {:>9} {:>8} {:>8} {:>8} {:>8} {:>7} {:>9}",
            "engine", "res", "EPE px", "bad-1 %", "bad-2 %", "bad-3 %", "valid", "ms"
        );
        for s in &rows {
            println!(
                "{:<18} {:>9} {:>8.3} {:>8.2} {:>8.2} {:>8.2} {:>7.3} {:>9.2}",
                s["engine"].as_str().unwrap_or(""),
                s["resolution"].as_str().unwrap_or(""),
                s["epe_px"].as_f64().unwrap_or(f64::NAN),
                s["bad1_pct"].as_f64().unwrap_or(f64::NAN),
                s["bad2_pct"].as_f64().unwrap_or(f64::NAN),
                s["bad3_pct"].as_f64().unwrap_or(f64::NAN),
                s["valid_fraction"].as_f64().unwrap_or(f64::NAN),
                s["ms_median"].as_f64().unwrap_or(f64::NAN)
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}
