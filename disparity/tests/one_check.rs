//! One left-right check for every caller: `estimate` (what `abvs disparity --confidence` writes) and
//! [`LrCheck::run`] on an engine from the factory (what the runtime's disparity stage runs) give the same
//! confidence, bit for bit, for the fused engine (its own check) and for SGBM (the generic one). Real ONNX
//! Runtime with the shipped hitnet-s at its 320x240.
use abvs_disparity::confidence::{reason, LrCheck};
use abvs_disparity::estimate::estimate;
use abvs_disparity::factory::engine;
use abvs_disparity::fused::{FusedEngine, Source};
use abvs_disparity::manifest::shipped;
use abvs_disparity::onnx::OnnxEngine;
use abvs_runtime_core::params::CheckConfig;
use opencv::core::Mat;
use opencv::prelude::*;

/// A textured pair whose right view is the left shifted by 6 px (value noise, smooth enough for both engines).
fn pair(w: usize, h: usize) -> (Vec<u8>, Vec<u8>) {
    let tex = |x: f32, y: usize| {
        let f = (x * 0.37).sin() * 60.0 + (x * 0.113 + y as f32 * 0.71).cos() * 50.0 + (y as f32 * 0.23).sin() * 20.0;
        (f + 128.0).clamp(0.0, 255.0) as u8
    };
    let left = (0..w * h).map(|i| tex((i % w) as f32, i / w)).collect();
    let right = (0..w * h).map(|i| tex((i % w) as f32 + 6.0, i / w)).collect();
    (left, right)
}

fn mat(v: &[u8], w: usize, h: usize) -> Mat {
    Mat::new_rows_cols_with_data(h as i32, w as i32, v).unwrap().try_clone().unwrap()
}

#[test]
fn estimate_and_the_stage_check_share_one_confidence() {
    let (w, h) = (320usize, 240usize);
    let (l, r) = pair(w, h);
    let model = shipped("hitnet-s");
    for kind in ["fused", "sgbm"] {
        // at the model's own resolution and its range (40 px), so that both callers run the same engine
        let est = estimate(&mat(&l, w, h), &mat(&r, w, h), kind, &model, 1, Some(1.0)).unwrap();
        let (conf, why) = est.checked.expect("checked");
        let mut e = engine(kind, Some(&model), (w as u32, h as u32), 40.0, 1).unwrap();
        let mut d = vec![f32::NAN; w * h];
        e.compute(&l, &r, &mut d).unwrap();
        let mut check = LrCheck::new(CheckConfig { confidence: true, invalidate: true, max_diff: 1.0 }).unwrap();
        check.start(w as u32, h as u32);
        let (mut c2, mut why2) = (vec![0f32; w * h], vec![0u8; w * h]);
        let valid = vec![1u8; w * h];
        check.run(e.as_mut(), &l, &r, Some(&valid), &mut d, Some(&mut c2), Some(&mut why2)).unwrap();
        assert!(conf.iter().zip(&c2).all(|(a, b)| a.to_bits() == b.to_bits()), "{kind}: confidence differs");
        assert_eq!(why, why2, "{kind}: reasons differ");
        let same = est.disparity.iter().zip(&d).all(|(a, b)| a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()));
        assert!(same, "{kind}: checked disparity differs");
        let passed = why.iter().filter(|r| **r == reason::VALID).count();
        assert!(passed > w * h / 2, "{kind}: {passed} pixels passed");
    }
}

#[test]
fn the_fused_check_ranks_accepted_sgbm_matches_above_every_network_pixel() {
    let (w, h) = (320usize, 240usize);
    let (l, r) = pair(w, h);
    let net = OnnxEngine::load(&shipped("hitnet-s"), 1).unwrap();
    let mut e = FusedEngine::new(net, w as u32, h as u32).unwrap();
    let mut d = vec![f32::NAN; w * h];
    use abvs_disparity::engine::DisparityEngine;
    e.compute(&l, &r, &mut d).unwrap();
    let sources = e.sources().to_vec();
    let mut check = LrCheck::new(CheckConfig { confidence: true, invalidate: false, max_diff: 1.0 }).unwrap();
    check.start(w as u32, h as u32);
    let (mut conf, mut why) = (vec![0f32; w * h], vec![0u8; w * h]);
    check.run(&mut e, &l, &r, None, &mut d, Some(&mut conf), Some(&mut why)).unwrap();
    let (mut sgbm, mut network) = (0, 0);
    for i in 0..w * h {
        match sources[i] {
            Source::Sgbm => {
                sgbm += 1;
                assert!((0.5..=1.0).contains(&conf[i]) && why[i] == reason::VALID, "pixel {i}: {}", conf[i]);
            }
            Source::Network => {
                network += 1;
                assert!((0.0..=0.5).contains(&conf[i]), "pixel {i}: {}", conf[i]);
                assert_eq!(conf[i] > 0.0, why[i] == reason::VALID, "pixel {i}");
                // without `invalidate` the disparity stays
                assert!(d[i].is_finite());
            }
            Source::None => assert_eq!((conf[i], why[i]), (0.0, reason::NO_ESTIMATE)),
        }
    }
    assert!(sgbm > w * h / 2 && network > 0, "SGBM {sgbm}, network {network} pixels");
}
