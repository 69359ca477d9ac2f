//! Per-stage costs of the runtime at the two network resolutions: rectification map build (coarse grid +
//! cubic, against the exact per-pixel build as the baseline) and remap for both eyes, disparity (SGBM and the
//! shipped networks), depth + cloud. End-to-end latency and throughput come from `abvs run` (BENCHMARKS.md).
use std::path::Path;

use abvs_camera::Camera;
use abvs_disparity::census::{census_rows, CensusRefineEngine};
use abvs_disparity::census_confidence::Scorer;
use abvs_disparity::confidence::mask;
use abvs_disparity::engine::DisparityEngine;
use abvs_disparity::match_cost::{Codes, MatchCost};
use abvs_disparity::onnx::OnnxEngine;
use abvs_disparity::resample::nearest;
use abvs_disparity::sgbm::SgbmEngine;
use abvs_eye::{Fick, Pose};
use abvs_runtime::tasks::depth::DepthConfig;
use abvs_runtime::tasks::rectify::{rectify, StereoRectifier};
use abvs_runtime_core::messages::DepthFrame;
use abvs_runtime_core::messages::RectifiedCamera;
use abvs_runtime_core::params::DEFAULT_MIN_CONFIDENCE;
use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::Vector3;

fn extrinsic() -> Pose {
    Pose::new(Fick::from_deg([2.0, -1.0, 6.0]).to_matrix(), Vector3::new(-0.0648, 0.0012, 0.004))
}

fn bench(c: &mut Criterion) {
    let raw = Camera::ov8856().scaled(800, 600);
    let models = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/hitnet");
    // wrapping: the noise the release builds always drew (a debug build panicked on the overflow)
    let img: Vec<u8> = (0..800 * 600i32).map(|i| (i.wrapping_mul(7919) % 251) as u8).collect();
    for (w, h, variant) in [(320u32, 240u32, "hitnet-s"), (640, 480, "hitnet-m")] {
        let out = RectifiedCamera::with_hfov(w, h, 100.0);
        let e = extrinsic();
        let mut g = c.benchmark_group(format!("runtime_{w}x{h}"));
        g.sample_size(20);
        let mut grid = StereoRectifier::new(raw, raw, out, 8).unwrap();
        g.bench_function("rectify_maps_both_eyes_grid8", |b| b.iter(|| grid.update(&e).unwrap()));
        let mut exact = StereoRectifier::new(raw, raw, out, 1).unwrap();
        g.bench_function("rectify_maps_both_eyes_exact_baseline", |b| b.iter(|| exact.update(&e).unwrap()));
        let rect = grid.update(&e).unwrap();
        let (mut l, mut r) = (vec![0u8; (w * h) as usize], vec![0u8; (w * h) as usize]);
        g.bench_function("remap_both_eyes", |b| {
            b.iter(|| {
                grid.left.remap(&img, 800, 600, &mut l).unwrap();
                grid.right.remap(&img, 800, 600, &mut r).unwrap();
            })
        });
        let mut disp = vec![0f32; (w * h) as usize];
        let mut sgbm = SgbmEngine::new(w, h, out.f * 0.065 / 0.2).unwrap();
        g.bench_function("disparity_sgbm", |b| b.iter(|| sgbm.compute(&l, &r, &mut disp).unwrap()));
        if models.join(variant).join("manifest.json").exists() {
            let mut onnx = OnnxEngine::load(&models.join(variant), 2).unwrap();
            g.bench_function(format!("disparity_onnx_{variant}_2threads"), |b| {
                b.iter(|| onnx.compute(&l, &r, &mut disp).unwrap())
            });
        }
        // the runtime's default engine, with and without its confidence and validity mask (issue 41: at most
        // +10 %), on the rectified noise pair
        let base = abvs_disparity::manifest::refine_base(&models.join(variant)).unwrap();
        if base.join("manifest.json").exists() {
            let census = |scored: bool| {
                let e = CensusRefineEngine::new(OnnxEngine::load(&base, 2).unwrap(), w, h).unwrap();
                if scored {
                    e
                } else {
                    e.without_confidence()
                }
            };
            let mut plain = census(false);
            g.bench_function("disparity_census_refine_baseline", |b| {
                b.iter(|| plain.compute(&l, &r, &mut disp).unwrap())
            });
            let mut scored = census(true);
            let (mut conf, mut why) = (vec![0f32; (w * h) as usize], vec![0u8; (w * h) as usize]);
            g.bench_function("disparity_census_refine_confidence_and_mask", |b| {
                b.iter(|| {
                    scored.compute(&l, &r, &mut disp).unwrap();
                    let (c, y) = scored.confidence().unwrap();
                    conf.copy_from_slice(c);
                    why.copy_from_slice(y);
                    mask(&conf, DEFAULT_MIN_CONFIDENCE, &mut disp, &mut why);
                })
            });
        }
        // the confidence's work alone on one thread, on a noise answer: the scoring at the search's resolution
        // (half the engine's), the match cost's census of both images at the engine's (on the rows it uses)
        // and the cost, the logistic and the nearest upsampling (in the engine the scoring and the census run
        // on its second thread while the answer is upsampled: the whole engine's pair above is what it adds to
        // the frame)
        {
            let (sw, sh) = (w as usize / 2, h as usize / 2);
            let n = sw * sh;
            let refined: Vec<f32> = (0..n).map(|i| 8.0 + ((i * 7919) % 13) as f32 * 0.5).collect();
            let net: Vec<f32> = refined.iter().map(|v| v + 0.3).collect();
            let prior: Vec<f32> = (0..n).map(|i| if i % 3 == 0 { f32::NAN } else { refined[i] }).collect();
            let stat: Vec<u8> = (0..n).map(|i| ((i * 31) % 256) as u8).collect();
            let mut scorer = Scorer::new(sw, sh);
            let (mut c, mut y) = (vec![0f32; n], vec![0u8; n]);
            let (mut cu, mut yu) = (vec![0f32; (w * h) as usize], vec![0u8; (w * h) as usize]);
            let (wu, hu) = (w as usize, h as usize);
            let (mut cl, mut cr, mut cost) =
                (vec![0u32; wu * sh], vec![0u32; wu * sh], MatchCost::new((wu, hu), (sw, sh)));
            let answer: Vec<f32> = (0..wu * hu).map(|i| 16.0 + ((i * 7919) % 13) as f32).collect();
            g.bench_function("census_confidence_scoring_only", |b| {
                b.iter(|| {
                    scorer.score(&l[..n], &stat, &refined, &net, Some(&prior), &mut c, &mut y);
                    census_rows(&l, wu, hu, cost.rows(), &mut cl);
                    census_rows(&r, wu, hu, cost.rows(), &mut cr);
                    Scorer::finish(&mut c, cost.compute(Codes::Rows(&cl, &cr), &answer));
                    nearest(&c, (sw, sh), &mut cu, (w as usize, h as usize));
                    nearest(&y, (sw, sh), &mut yu, (w as usize, h as usize));
                })
            });
        }
        let d: Vec<f32> = (0..(w * h) as usize).map(|i| 5.0 + (i % 30) as f32).collect();
        let mut depth = DepthFrame::new(w, h);
        let cfg = DepthConfig::default();
        g.bench_function("depth_and_cloud", |b| {
            b.iter(|| {
                abvs_runtime::tasks::depth::compute(&mut depth, &d, |_| true, &l, &out, &rect, &Pose::identity(), &cfg)
            })
        });
        let _ = rectify(&e);
        g.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
