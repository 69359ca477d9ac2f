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

use abvs_runtime::config::EngineKind;
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
    /// Model directory or .onnx (default: the shipped model of the largest resolution that fits in the
    /// input, so nothing is upsampled: hitnet-m (640x480) for inputs of at least 640x480, else hitnet-s).
    #[arg(long)]
    model: Option<PathBuf>,
    #[arg(long, value_enum, default_value_t = EngineKind::Onnx)]
    engine: EngineKind,
    #[arg(long, default_value_t = 2)]
    threads: usize,
    /// Left-right consistency check: the right view's disparity is computed too (the pair mirrored and
    /// swapped) and a left pixel whose match disagrees by more than --lr-max-diff (px at the engine's
    /// resolution) or falls outside the right image is invalid.
    #[arg(long)]
    lr_check: bool,
    #[arg(long, default_value_t = 1.0)]
    lr_max_diff: f32,
    /// Per-pixel confidence in [0, 1] as PFM at the input resolution: exp(-|d_left - d_right|) of the
    /// left-right check (implies it), 0 where invalid.
    #[arg(long)]
    confidence: Option<PathBuf>,
    /// Why each pixel is invalid, as an 8-bit PNG at the input resolution: 0 valid, 1 no estimate from the
    /// engine (e.g. beyond its disparity range), 2 its match falls outside the right image, 3 left-right
    /// check failed (occlusion or mismatch). Implies the left-right check.
    #[arg(long)]
    invalid_reason: Option<PathBuf>,
}

/// Codes of `--invalid-reason`.
const VALID: u8 = 0;
const NO_ESTIMATE: u8 = 1;
const OUTSIDE_RIGHT: u8 = 2;
const LR_FAILED: u8 = 3;

/// The left-right check at the engine's resolution: per pixel, the reason code and the confidence.
fn lr_check(dl: &[f32], dr: &[f32], w: usize, max_diff: f32) -> (Vec<u8>, Vec<f32>) {
    let mut reason = vec![VALID; dl.len()];
    let mut conf = vec![0f32; dl.len()];
    for (i, &d) in dl.iter().enumerate() {
        let x = (i % w) as f32;
        if !d.is_finite() {
            reason[i] = NO_ESTIMATE;
            continue;
        }
        let xr = (x - d).round();
        if xr < 0.0 {
            reason[i] = OUTSIDE_RIGHT;
            continue;
        }
        let back = dr[i - (i % w) + xr as usize];
        let diff = (d - back).abs();
        if !back.is_finite() || diff > max_diff {
            reason[i] = LR_FAILED;
            continue;
        }
        conf[i] = (-diff).exp();
    }
    (reason, conf)
}

/// Each row of a `w`-wide image reversed (the mirror that turns a right view into a left one).
fn mirror<T: Copy>(img: &[T], w: usize) -> Vec<T> {
    img.chunks(w).flat_map(|row| row.iter().rev().copied()).collect()
}

/// Nearest-neighbour resample of a model-resolution map to the input resolution.
fn to_input<T: Copy>(m: &[T], (mw, mh): (usize, usize), (iw, ih): (usize, usize), fill: T) -> Vec<T> {
    let mut out = vec![fill; iw * ih];
    for y in 0..ih {
        let yy = (((y as f32 + 0.5) * mh as f32 / ih as f32) as usize).min(mh - 1);
        for x in 0..iw {
            let xx = (((x as f32 + 0.5) * mw as f32 / iw as f32) as usize).min(mw - 1);
            out[y * iw + x] = m[yy * mw + xx];
        }
    }
    out
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

/// Largest PFM the tools read (values): 2^28 floats = 1 GiB, far above any disparity map.
pub const MAX_PFM_VALUES: usize = 1 << 28;

/// Reads a grayscale PFM into row-major top-to-bottom order.
pub fn read_pfm(path: &Path) -> anyhow::Result<(usize, usize, Vec<f32>)> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    parse_pfm(&bytes).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// Parses a grayscale PFM ("Pf", width, height, scale: negative = little-endian, then rows bottom to top).
/// Every malformed input is an error, never a panic: a bad or truncated header, a size of 0 or beyond
/// [`MAX_PFM_VALUES`], a scale that is 0 or not a number, too little data. Trailing bytes are ignored.
pub fn parse_pfm(bytes: &[u8]) -> Result<(usize, usize, Vec<f32>), String> {
    let mut fields: Vec<&[u8]> = Vec::with_capacity(4);
    let mut pos = 0;
    while fields.len() < 4 {
        while pos < bytes.len() && bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        let start = pos;
        while pos < bytes.len() && !bytes[pos].is_ascii_whitespace() && pos - start < 64 {
            pos += 1;
        }
        if start == pos {
            return Err(format!("truncated PFM header ({} of 4 fields: Pf, width, height, scale)", fields.len()));
        }
        if pos < bytes.len() && !bytes[pos].is_ascii_whitespace() {
            return Err("PFM header field longer than 64 bytes".into());
        }
        fields.push(&bytes[start..pos]);
    }
    // exactly one whitespace byte ends the header
    if pos >= bytes.len() {
        return Err("PFM header not followed by data".into());
    }
    pos += 1;
    let text = |f: &[u8]| String::from_utf8_lossy(f).into_owned();
    if fields[0] != b"Pf" {
        return Err(format!("`{}` is not a grayscale PFM (expected Pf)", text(fields[0])));
    }
    let dim = |f: &[u8], what: &str| -> Result<usize, String> {
        let v: usize = std::str::from_utf8(f)
            .ok()
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| format!("{what} `{}` is not a whole number", text(f)))?;
        if v == 0 {
            return Err(format!("{what} is 0"));
        }
        Ok(v)
    };
    let w = dim(fields[1], "width")?;
    let h = dim(fields[2], "height")?;
    let n = w
        .checked_mul(h)
        .filter(|&n| n <= MAX_PFM_VALUES)
        .ok_or_else(|| format!("{w}x{h} exceeds the largest PFM read ({MAX_PFM_VALUES} values)"))?;
    let scale: f32 = std::str::from_utf8(fields[3])
        .ok()
        .and_then(|s| s.parse().ok())
        .filter(|s: &f32| s.is_finite() && *s != 0.0)
        .ok_or_else(|| format!("scale `{}` is not a finite non-zero number", text(fields[3])))?;
    let have = bytes.len() - pos;
    if have < n * 4 {
        return Err(format!("{have} bytes of data for {w}x{h} (expected {})", n * 4));
    }
    let data = &bytes[pos..pos + n * 4];
    let mut out = vec![0f32; n];
    for (y, row) in out.chunks_exact_mut(w).enumerate() {
        let src = &data[(h - 1 - y) * w * 4..(h - y) * w * 4];
        for (o, b) in row.iter_mut().zip(src.chunks_exact(4)) {
            let b = [b[0], b[1], b[2], b[3]];
            *o = if scale < 0.0 { f32::from_le_bytes(b) } else { f32::from_be_bytes(b) };
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

/// The shipped model for an input of `w` x `h`: the largest resolution that fits in it (the network sees
/// the most detail without inventing any by upsampling); the smallest when none fits.
fn default_model_for(w: u32, h: u32) -> PathBuf {
    let size = |p: &PathBuf| -> Option<(u32, u32)> {
        let text = std::fs::read_to_string(p.join("manifest.json")).ok()?;
        let m: disparity::DisparityManifest = serde_json::from_str(&text).ok()?;
        Some((m.width, m.height))
    };
    let mut shipped: Vec<(PathBuf, (u32, u32))> =
        default_models().into_iter().filter_map(|p| size(&p).map(|s| (p, s))).collect();
    shipped.sort_by_key(|(_, (mw, mh))| mw * mh);
    let fits = shipped.iter().rev().find(|(_, (mw, mh))| *mw <= w && *mh <= h);
    match fits.or(shipped.first()) {
        Some((p, _)) => p.clone(),
        // none readable: the error names the expected path when it is loaded
        None => crate::run::shipped("models/hitnet/hitnet-s"),
    }
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
    let model = a.model.clone().unwrap_or_else(|| default_model_for(l.cols() as u32, l.rows() as u32));
    let onnx = disparity::OnnxEngine::load(&model, a.threads)?;
    let (mw, mh) = (onnx.manifest.width, onnx.manifest.height);
    let max = onnx.manifest.max_disparity;
    let mut engine: Box<dyn DisparityEngine> = match a.engine {
        EngineKind::Onnx => Box::new(onnx),
        EngineKind::Sgbm => Box::new(disparity::SgbmEngine::new(mw, mh, max)?),
    };
    let (lm, rm) = (resize_to(&l, mw as i32, mh as i32)?, resize_to(&r, mw as i32, mh as i32)?);
    let mut d = compute(engine.as_mut(), &lm, &rm)?;
    let (msize, isize) = ((mw as usize, mh as usize), (l.cols() as usize, l.rows() as usize));
    if a.lr_check || a.confidence.is_some() || a.invalid_reason.is_some() {
        // The right view's disparity: the mirrored right image is a left view of the mirrored left one.
        let w = mw as usize;
        let dr = mirror(&compute(engine.as_mut(), &mirror(&rm, w), &mirror(&lm, w))?, w);
        let (reason, conf) = lr_check(&d, &dr, w, a.lr_max_diff);
        for (v, &why) in d.iter_mut().zip(&reason) {
            if why != VALID {
                *v = f32::NAN;
            }
        }
        if let Some(p) = &a.confidence {
            write_pfm(p, isize.0, isize.1, &to_input(&conf, msize, isize, 0.0))?;
        }
        if let Some(p) = &a.invalid_reason {
            let codes = to_input(&reason, msize, isize, NO_ESTIMATE);
            image::GrayImage::from_raw(isize.0 as u32, isize.1 as u32, codes)
                .context("reason map size")?
                .save(p)
                .with_context(|| format!("writing {}", p.display()))?;
        }
    }
    // back to the input resolution, values scaled by the width ratio
    let (iw, ih) = isize;
    let sx = iw as f32 / mw as f32;
    let out: Vec<f32> = to_input(&d, msize, isize, f32::NAN).into_iter().map(|v| v * sx).collect();
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
    if gw == 0 || gh == 0 || g.len() < gw * gh {
        bail!("{}: empty ground-truth image ({gw}x{gh})", path.display());
    }
    if w == 0 || h == 0 {
        bail!("engine resolution {w}x{h} is empty");
    }
    let sx = w as f32 / gw as f32;
    let mut out = vec![f32::NAN; w as usize * h as usize];
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
    let s = abvs_sim::disparity_score::score_disparity(d, gt, max_disp);
    serde_json::json!({ "epe_px": s.epe_px, "bad1_pct": s.bad_pct[0], "bad2_pct": s.bad_pct[1],
        "bad3_pct": s.bad_pct[2], "valid_fraction": s.valid_fraction, "gt_pixels": s.gt_pixels })
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

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn pfm(w: usize, h: usize, scale: &str, data: &[f32]) -> Vec<u8> {
        let mut b = format!("Pf\n{w} {h}\n{scale}\n").into_bytes();
        for v in data {
            b.extend_from_slice(&if scale.starts_with('-') { v.to_le_bytes() } else { v.to_be_bytes() });
        }
        b
    }

    #[test]
    fn a_written_pfm_reads_back_in_both_byte_orders() {
        let d: Vec<f32> = (0..12).map(|i| i as f32 * 0.5).collect();
        // rows are stored bottom to top
        let stored: Vec<f32> = d.chunks(4).rev().flatten().copied().collect();
        for scale in ["-1.0", "1.0"] {
            assert_eq!(parse_pfm(&pfm(4, 3, scale, &stored)).unwrap(), (4, 3, d.clone()), "scale {scale}");
        }
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("d.pfm");
        write_pfm(&p, 4, 3, &d).unwrap();
        assert_eq!(read_pfm(&p).unwrap(), (4, 3, d));
    }

    #[test]
    fn each_documented_pfm_error() {
        let ok = pfm(2, 2, "-1.0", &[1.0; 4]);
        let cases: &[(&[u8], &str)] = &[
            (b"", "truncated PFM header"),
            (b"Pf\n2 2", "truncated PFM header"),
            (b"Pf\n2 2\n-1.0", "not followed by data"),
            (b"PF\n2 2\n-1.0\n", "not a grayscale PFM"),
            (b"Pf\n0 2\n-1.0\n", "width is 0"),
            (b"Pf\n2 -2\n-1.0\n", "height `-2` is not a whole number"),
            // w*h*4 overflows usize: refused before any allocation
            (b"Pf\n18446744073709551615 18446744073709551615\n-1.0\n", "exceeds the largest PFM"),
            (b"Pf\n65536 65536\n-1.0\n", "exceeds the largest PFM"),
            (b"Pf\n2 2\n0\n", "scale `0`"),
            (b"Pf\n2 2\nnan\n", "scale `nan`"),
            (b"Pf\n2 2\ninf\n", "scale `inf`"),
            (&ok[..ok.len() - 1], "15 bytes of data for 2x2 (expected 16)"),
        ];
        for (bytes, want) in cases {
            let e = parse_pfm(bytes).unwrap_err();
            assert!(e.contains(want), "{:?}: `{e}` lacks `{want}`", String::from_utf8_lossy(bytes));
        }
        // the path is named
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("cut.pfm");
        std::fs::write(&p, &ok[..14]).unwrap();
        let e = read_pfm(&p).unwrap_err().to_string();
        assert!(e.contains("cut.pfm") && e.contains("2 bytes of data for 2x2"), "{e}");
    }

    #[test]
    fn load_gt_refuses_an_empty_image_instead_of_underflowing() {
        let dir = tempfile::tempdir().unwrap();
        // a PFM cannot be empty (its reader refuses 0), a PNG can be 0 pixels only by not decoding: both errors
        let p = dir.path().join("gt.pfm");
        std::fs::write(&p, b"Pf\n0 0\n-1.0\n").unwrap();
        assert!(load_gt(&p, 1.0, 8, 8).is_err());
        let p = dir.path().join("gt.png");
        std::fs::write(&p, b"").unwrap();
        assert!(load_gt(&p, 1.0, 8, 8).is_err());
        // a 1x1 ground truth scales to any size
        let p = dir.path().join("one.pfm");
        std::fs::write(&p, pfm(1, 1, "-1.0", &[2.0])).unwrap();
        let (_, _, g) = load_gt(&p, 1.0, 4, 3).unwrap();
        assert_eq!(g, vec![8.0; 12]);
        assert!(load_gt(&p, 1.0, 0, 3).is_err());
    }

    fn mutate(mut b: Vec<u8>, edits: &[(usize, u8, u8)]) -> Vec<u8> {
        for &(at, kind, v) in edits {
            if b.is_empty() {
                b.push(v);
                continue;
            }
            let i = at % b.len();
            match kind % 4 {
                0 => b[i] = v,
                1 => {
                    b.remove(i);
                }
                2 => b.insert(i, v),
                _ => b.truncate(i),
            }
        }
        b
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

        /// Random bytes: an error or a map, never a panic.
        #[test]
        fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..256)) {
            if let Ok((w, h, d)) = parse_pfm(&bytes) {
                prop_assert_eq!(d.len(), w * h);
            }
        }

        /// Random headers (digits, signs, huge sizes) in front of some data.
        #[test]
        fn random_headers_never_panic(
            w in "[-+0-9a-z]{0,22}", h in "[-+0-9a-z]{0,22}", scale in "[-+0-9.eEinfa]{0,8}",
            sep in "[ \n\t]{1,3}", data in proptest::collection::vec(any::<u8>(), 0..128),
        ) {
            let mut b = format!("Pf{sep}{w}{sep}{h}{sep}{scale}{sep}").into_bytes();
            b.extend_from_slice(&data);
            if let Ok((w, h, d)) = parse_pfm(&b) {
                prop_assert_eq!(d.len(), w * h);
                prop_assert!(w * h * 4 <= b.len());
            }
        }

        /// Valid files mutated (bytes changed, removed, inserted, cut): an error or a map, never a panic.
        #[test]
        fn mutated_files_never_panic(
            w in 1usize..6, h in 1usize..6, le in any::<bool>(),
            edits in proptest::collection::vec((any::<usize>(), any::<u8>(), any::<u8>()), 1..6),
        ) {
            let data: Vec<f32> = (0..w * h).map(|i| i as f32).collect();
            let b = mutate(pfm(w, h, if le { "-1.0" } else { "1.0" }, &data), &edits);
            if let Ok((w2, h2, d)) = parse_pfm(&b) {
                prop_assert_eq!(d.len(), w2 * h2);
            }
        }
    }
}
