//! `abvs disparity` / `abvs disparity-eval` with the shipped network (real ONNX Runtime) and OpenCV SGBM.
use std::path::Path;
use std::process::Command;

fn abvs() -> Command {
    Command::new(env!("CARGO_BIN_EXE_abvs"))
}

/// Reads a PFM the program wrote, through the library's reader (the one the program's `disparity-eval` uses),
/// refusing any but the little-endian layout `abvs disparity` writes.
fn read_pfm(p: &Path) -> (usize, usize, Vec<f32>) {
    let b = std::fs::read(p).unwrap();
    assert!(b.starts_with(b"Pf\n") && String::from_utf8_lossy(&b[..b.len().min(32)]).contains("\n-1.0\n"));
    abvs_disparity::pfm::read_pfm(p).unwrap_or_else(|e| panic!("{e}"))
}

/// A rectified pair rendered from the synthetic scene through two pinhole cameras 65 mm apart, and its exact
/// disparity (f B / Z from the renderer's depth).
fn rendered_pair(dir: &Path, (w, h): (u32, u32)) -> (usize, usize, Vec<f32>) {
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
    let f = (w as f64 / 2.0) / 50f64.to_radians().tan();
    let cam = abvs_camera::Camera::pinhole(w, h, f);
    let scene = abvs_sim::synth::scene(7).unwrap();
    let look = UnitQuaternion::from_euler_angles(0.1, -0.15, 0.0);
    let opts = abvs_render::RenderOptions { supersample: 2, noise_sigma: 1.5, seed: 3, ..Default::default() };
    let left = Isometry3::from_parts(Translation3::identity(), look);
    let right = Isometry3::from_parts(Translation3::from(look * Vector3::new(0.065, 0.0, 0.0)), look);
    let l = abvs_render::render(&scene, &cam, &left, &opts).unwrap();
    let r = abvs_render::render(&scene, &cam, &right, &opts).unwrap();
    l.gray_image().save(dir.join("left.png")).unwrap();
    r.gray_image().save(dir.join("right.png")).unwrap();
    let gt = l.depth.iter().map(|z| if z.is_finite() { (f * 0.065 / *z as f64) as f32 } else { f32::NAN }).collect();
    (w as usize, h as usize, gt)
}

/// Runs `abvs disparity` with `engine` (and `model`) on the pair in `dir`; returns EPE over the pixels it
/// answers, bad-2 % (unanswered pixels count as bad) and the answered fraction, over GT below `max_d`.
fn score(dir: &Path, engine: &str, model: Option<&Path>, (gw, gh): (usize, usize), gt: &[f32], max_d: f32) -> [f64; 3] {
    let out = dir.join(format!("{engine}.pfm"));
    let mut cmd = abvs();
    cmd.args(["disparity", "--engine", engine, "--left"])
        .arg(dir.join("left.png"))
        .arg("--right")
        .arg(dir.join("right.png"))
        .arg("--out")
        .arg(&out);
    if let Some(m) = model {
        cmd.arg("--model").arg(m);
    }
    let o = cmd.output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (w, h, disp) = read_pfm(&out);
    assert_eq!((w, h), (gw, gh));
    assert!(disp.iter().all(|v| !v.is_nan()), "invalid is written as inf, never NaN");
    let s = abvs_disparity::score::score_disparity(&disp, gt, max_d as f64);
    let r = [s.epe_px, s.bad_pct[1], s.valid_fraction];
    eprintln!("{engine} {model:?} {gw}x{gh}: EPE {:.3} px, bad-2 {:.1}%, valid {:.3}", r[0], r[1], r[2]);
    r
}

#[test]
fn the_shipped_network_recovers_a_rendered_pair_and_writes_pfm() {
    let d = tempfile::tempdir().unwrap();
    let (gw, gh, gt) = rendered_pair(d.path(), (320, 240));
    let net = score(d.path(), "onnx", None, (gw, gh), &gt, 40.0);
    score(d.path(), "sgbm", None, (gw, gh), &gt, 40.0);
    // stated bound for the shipped hitnet-s on a rendered pair of our scene generator
    assert!(net[0] < 1.0, "network EPE {} px", net[0]); // 0.22 px when written
}

#[test]
fn the_shipped_640x480_network_recovers_a_rendered_pair() {
    let d = tempfile::tempdir().unwrap();
    let (gw, gh, gt) = rendered_pair(d.path(), (640, 480));
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/hitnet/hitnet-m");
    let net = score(d.path(), "onnx", Some(&model), (gw, gh), &gt, 80.0);
    let sgbm = score(d.path(), "sgbm", None, (gw, gh), &gt, 80.0);
    // stated bounds for the shipped hitnet-m on a rendered pair of our scene generator
    assert!(net[0] < 0.6, "hitnet-m EPE {} px", net[0]); // 0.24 px when written
    assert!(net[1] < sgbm[1], "hitnet-m bad-2 {} % vs SGBM {} %", net[1], sgbm[1]);
}

#[test]
fn disparity_eval_scores_both_engines_on_the_real_aloe_pair() {
    let data = Path::new("/usr/share/doc/opencv-doc/examples/data");
    if !data.join("aloeGT.png").exists() {
        panic!("opencv-doc is not installed: run scripts/setup.sh (it provides the Middlebury Aloe pair)");
    }
    let o = abvs()
        .args(["disparity-eval", "--at-model-resolution", "--json", "--runs", "3", "--left"])
        .arg(data.join("aloeL.jpg"))
        .arg("--right")
        .arg(data.join("aloeR.jpg"))
        .arg("--gt")
        .arg(data.join("aloeGT.png"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rows: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let rows = rows.as_array().unwrap();
    assert!(rows.len() >= 2);
    for r in rows {
        let bad2 = r["bad2_pct"].as_f64().unwrap();
        assert!(r["gt_pixels"].as_u64().unwrap() > 50_000, "{r}");
        assert!(bad2 > 0.0 && bad2 < 60.0, "{r}");
        assert!(r["ms_median"].as_f64().unwrap() > 0.0);
    }
    // At each resolution the shipped network has fewer bad pixels than SGBM on this real pair (hitnet-s
    // 22.8 vs 29.9 %, hitnet-m 23.6 vs 25.5 % when written). Aloe is the pair the models were chosen on,
    // so this checks the claim as made, not generalisation to pairs the models never saw.
    for res in ["320x240", "640x480"] {
        let bad2 = |net: bool| {
            rows.iter()
                .find(|r| r["resolution"] == res && r["engine"].as_str().unwrap().starts_with("onnx") == net)
                .unwrap_or_else(|| panic!("no {} row at {res}: {rows:?}", if net { "network" } else { "sgbm" }))
                ["bad2_pct"]
                .as_f64()
                .unwrap()
        };
        assert!(bad2(true) < bad2(false), "{res}: network bad-2 {} % vs SGBM {} %", bad2(true), bad2(false));
    }
}

#[test]
fn a_model_with_the_wrong_inputs_is_refused() {
    let d = tempfile::tempdir().unwrap();
    rendered_pair(d.path(), (320, 240));
    // a real ONNX model that is not a stereo network: an FK network (theta [N,3] -> pose [N,6])
    use abvs_calib::mlp::{Affine, Net};
    let fk = d.path().join("fk_net.onnx");
    abvs_calib::onnx_io::export_onnx(&Net::m1(8, 2, Affine::identity(3), Affine::identity(6), 1), &fk).unwrap();
    let o = abvs()
        .args(["disparity", "--left"])
        .arg(d.path().join("left.png"))
        .arg("--right")
        .arg(d.path().join("right.png"))
        .arg("--out")
        .arg(d.path().join("x.pfm"))
        .arg("--model")
        .arg(&fk)
        .output()
        .unwrap();
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains(fk.file_name().unwrap().to_str().unwrap()) && e.contains("[1,2,H,W]"), "{e}");
}

/// Without --model, `abvs disparity` takes the shipped model of the largest resolution that fits in the input:
/// hitnet-m (640x480) for the real Aloe pair (1282x1110), hitnet-s (320x240) for a 320x240 pair.
#[test]
fn the_default_model_suits_the_input_size() {
    let data = Path::new("/usr/share/doc/opencv-doc/examples/data");
    assert!(data.join("aloeL.jpg").exists(), "opencv-doc is not installed: run scripts/setup.sh");
    let d = tempfile::tempdir().unwrap();
    rendered_pair(d.path(), (320, 240));
    for (l, r, want) in [
        (data.join("aloeL.jpg"), data.join("aloeR.jpg"), "at 640x480"),
        (d.path().join("left.png"), d.path().join("right.png"), "at 320x240"),
    ] {
        let o = abvs()
            .args(["disparity", "--out"])
            .arg(d.path().join("d.pfm"))
            .arg("--left")
            .arg(&l)
            .arg("--right")
            .arg(&r)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success() && err.contains(want), "{}: {err}", l.display());
    }
}

/// Validity and confidence on the real Aloe pair: the left-right check removes pixels and those it keeps are
/// more often right; the confidence ranks pixels by how often they are right; the reason map says why each
/// removed pixel is invalid and nothing else.
#[test]
fn left_right_check_confidence_and_invalid_reasons_on_a_real_pair() {
    let data = Path::new("/usr/share/doc/opencv-doc/examples/data");
    assert!(data.join("aloeGT.png").exists(), "opencv-doc is not installed: run scripts/setup.sh");
    let d = tempfile::tempdir().unwrap();
    let run = |extra: &[&str], out: &str| {
        let o = abvs()
            .args(["disparity", "--left"])
            .arg(data.join("aloeL.jpg"))
            .arg("--right")
            .arg(data.join("aloeR.jpg"))
            .arg("--out")
            .arg(d.path().join(out))
            .args(extra)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        read_pfm(&d.path().join(out))
    };
    let (w, h, plain) = run(&[], "plain.pfm");
    let (conf_p, why_p) = (d.path().join("conf.pfm"), d.path().join("why.png"));
    let (_, _, checked) =
        run(&["--confidence", conf_p.to_str().unwrap(), "--invalid-reason", why_p.to_str().unwrap()], "lr.pfm");
    let (cw, ch, conf) = read_pfm(&conf_p);
    let why = image::open(&why_p).unwrap().to_luma8();
    assert_eq!((cw, ch, why.width() as usize, why.height() as usize), (w, h, w, h));
    let gt = image::open(data.join("aloeGT.png")).unwrap().to_luma8();
    assert_eq!((gt.width() as usize, gt.height() as usize), (w, h));
    // bad-2 (%) over the ground-truth pixels a map answers, and the share of ground-truth pixels it answers
    let bad2 = |m: &[f32], keep: &dyn Fn(usize) -> bool| {
        let (mut n, mut bad, mut all) = (0usize, 0usize, 0usize);
        for (i, g) in gt.as_raw().iter().enumerate() {
            if *g == 0 {
                continue;
            }
            all += 1;
            if m[i].is_finite() && keep(i) {
                n += 1;
                bad += ((m[i] - *g as f32).abs() > 2.0) as usize;
            }
        }
        (100.0 * bad as f64 / n.max(1) as f64, n as f64 / all as f64)
    };
    let (b_plain, f_plain) = bad2(&plain, &|_| true);
    let (b_lr, f_lr) = bad2(&checked, &|_| true);
    let (b_hi, f_hi) = bad2(&checked, &|i| conf[i] > 0.8);
    eprintln!("bad-2 / answered: plain {b_plain:.1} % / {f_plain:.3}, left-right {b_lr:.1} % / {f_lr:.3}, confidence > 0.8 {b_hi:.1} % / {f_hi:.3}");
    assert!(f_lr < f_plain && f_lr > 0.4, "answered {f_lr} vs {f_plain}");
    assert!(b_lr < 0.7 * b_plain, "the check keeps bad pixels: {b_lr} vs {b_plain} %");
    assert!(b_hi < b_lr && f_hi > 0.2, "confidence does not rank: {b_hi} % over {f_hi} vs {b_lr} %");
    // reasons: 0 exactly where a disparity is given, confidence 0 elsewhere, every code known, occlusions found
    let mut seen = [0usize; 4];
    for (i, c) in why.as_raw().iter().enumerate() {
        assert!(*c <= 3, "code {c}");
        seen[*c as usize] += 1;
        assert_eq!(*c == 0, checked[i].is_finite(), "pixel {i}: code {c}, disparity {}", checked[i]);
        assert!((0.0..=1.0).contains(&conf[i]) && (*c == 0 || conf[i] == 0.0), "pixel {i}: confidence {}", conf[i]);
    }
    eprintln!("reasons (valid, no estimate, outside the right image, left-right): {seen:?}");
    assert!(seen[3] > 0 && seen[2] > 0, "{seen:?}");
}
