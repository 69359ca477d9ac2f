//! What census-refine's confidence and validity mask add to the disparity stage (issue 41: at most +10 %), paired on a
//! loaded machine: two engines of the runtime's default at 640x480 (hitnet-m's refine base, hitnet-s with the SGBM
//! prior at 320x240), one scoring its pixels and masking at the default threshold as the runtime's disparity stage does
//! (`own_mask`: the confidence and reasons copied into the frame and the disparity masked in one pass, `mask_into`),
//! one without its confidence (`without_confidence`, the baseline). Each round runs the two arms alternately frame by
//! frame (which goes first alternates), REPS frames each, and takes the ratio of the arms' median frame times; prints
//! every round and the median of the ratios. Also times, interleaved with the arms, the added work alone on one thread
//! (the scoring at the search's 320x240 on the engine's own internals, the census of both images at 640x480 on the rows
//! the match cost uses and the cost, the logistic, the nearest upsampling and the mask): its CPU time. The engine runs
//! the scoring and the census on its second thread while the answer is upsampled, and the cost in halves on both, so
//! the arms' ratio, not this, is what it adds to the frame. Not in either: the census search's second-best tracking
//! (the margin byte), which both arms compute.
//! `cargo run --release -p abvs-disparity --example confidence_cost -- LEFT RIGHT [ROUNDS] [REPS]`
//! (scripts/bench_confidence_cost.sh).
use std::time::Instant;

use abvs_disparity::census::{census_rows, CensusRefineEngine};
use abvs_disparity::census_confidence::Scorer;
use abvs_disparity::confidence::{mask, mask_into};
use abvs_disparity::engine::{set_opencv_threads, DisparityEngine};
use abvs_disparity::match_cost::{Codes, MatchCost};
use abvs_disparity::onnx::OnnxEngine;
use abvs_disparity::resample::nearest;
use abvs_runtime_core::params::DEFAULT_MIN_CONFIDENCE;
use opencv::core::{Mat, Size};
use opencv::prelude::*;
use opencv::{imgcodecs, imgproc};

fn load(p: &str, w: i32, h: i32) -> Vec<u8> {
    let m = imgcodecs::imread(p, imgcodecs::IMREAD_GRAYSCALE).unwrap();
    assert!(!m.empty(), "{p}: not an image");
    let mut r = Mat::default();
    imgproc::resize(&m, &mut r, Size::new(w, h), 0.0, 0.0, imgproc::INTER_AREA).unwrap();
    r.data_bytes().unwrap().to_vec()
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    assert!(a.len() >= 3, "usage: confidence_cost LEFT RIGHT [ROUNDS] [REPS]");
    let rounds: usize = a.get(3).map_or(9, |s| s.parse().unwrap());
    let reps: usize = a.get(4).map_or(10, |s| s.parse().unwrap());
    set_opencv_threads(2).unwrap();
    let (w, h) = (640u32, 480u32);
    let (l, r) = (load(&a[1], w as i32, h as i32), load(&a[2], w as i32, h as i32));
    let models = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/hitnet/hitnet-m");
    let base = abvs_disparity::manifest::refine_base(&models).unwrap();
    let engine = || CensusRefineEngine::new(OnnxEngine::load(&base, 2).unwrap(), w, h).unwrap();
    let (mut on, mut off) = (engine(), engine().without_confidence());
    let n = (w * h) as usize;
    let (mut d_on, mut d_off) = (vec![0f32; n], vec![0f32; n]);
    let (mut conf, mut why) = (vec![0f32; n], vec![0u8; n]);
    // the rectified frame's pixels that see the raw image (all, on a pair that is rectified already)
    let seen = vec![1u8; n];
    // the added work alone, on the scored engine's internals at the search's resolution
    on.compute(&l, &r, &mut d_on).unwrap();
    let (nl, _, stat, refined, net, prior) = on.internals().unwrap();
    let (nl, stat, refined, net, prior) = (nl.to_vec(), stat.to_vec(), refined.to_vec(), net.to_vec(), prior.to_vec());
    let (sw, sh) = (w as usize / 2, h as usize / 2);
    let mut scorer = Scorer::new(sw, sh);
    let (mut cs, mut ys) = (vec![0f32; sw * sh], vec![0u8; sw * sh]);
    let (mut cu, mut yu, mut dm) = (vec![0f32; n], vec![0u8; n], d_on.clone());
    // the census codes of the rows the match cost uses (one per grid row), as the engine computes them
    let (mut cl, mut cr, answer) = (vec![0u32; w as usize * sh], vec![0u32; w as usize * sh], d_on.clone());
    let mut cost = MatchCost::new((w as usize, h as usize), (sw, sh));
    let mut added = || -> f64 {
        let t = Instant::now();
        scorer.score(&nl, &stat, &refined, &net, Some(&prior), &mut cs, &mut ys);
        census_rows(&l, w as usize, h as usize, cost.rows(), &mut cl);
        census_rows(&r, w as usize, h as usize, cost.rows(), &mut cr);
        Scorer::finish(&mut cs, cost.compute(Codes::Rows(&cl, &cr), &answer));
        nearest(&cs, (sw, sh), &mut cu, (w as usize, h as usize));
        nearest(&ys, (sw, sh), &mut yu, (w as usize, h as usize));
        mask(&cu, DEFAULT_MIN_CONFIDENCE, &mut dm, &mut yu);
        t.elapsed().as_secs_f64() * 1e3
    };
    let mut t_added = Vec::new();
    let mut run = |scored: bool| -> f64 {
        let t = Instant::now();
        if scored {
            on.compute(&l, &r, &mut d_on).unwrap();
            let (c, y) = on.confidence().unwrap();
            mask_into(c, y, &seen, DEFAULT_MIN_CONFIDENCE, &mut d_on, &mut conf, &mut why);
        } else {
            off.compute(&l, &r, &mut d_off).unwrap();
        }
        t.elapsed().as_secs_f64() * 1e3
    };
    // warm-up: the ONNX session's first runs, the caches
    for _ in 0..3 {
        run(true);
        run(false);
    }
    let mut ratios = Vec::new();
    let (mut all_on, mut all_off) = (Vec::new(), Vec::new());
    for round in 0..rounds {
        let (mut t_on, mut t_off) = (Vec::new(), Vec::new());
        for i in 0..reps {
            let first_on = (round + i) % 2 == 0;
            for scored in [first_on, !first_on] {
                let ms = run(scored);
                if scored { &mut t_on } else { &mut t_off }.push(ms);
            }
            t_added.push(added());
        }
        all_on.extend_from_slice(&t_on);
        all_off.extend_from_slice(&t_off);
        let (m_on, m_off) = (median(&mut t_on), median(&mut t_off));
        ratios.push(m_on / m_off);
        println!("round {round}: confidence+mask {m_on:.2} ms, without {m_off:.2} ms, ratio {:.4}", m_on / m_off);
    }
    let base = median(&mut all_off.clone());
    let add = median(&mut t_added);
    println!(
        "the added work alone on one thread (scoring at {sw}x{sh}, census at {w}x{h}, match cost, upsampling, \
         mask): median {add:.3} ms over {} runs; 1 + that / the baseline's median frame = {:.4} (the engine runs \
         the scoring and the census on its second thread while it upsamples: the arms' ratio is what it adds)",
        t_added.len(),
        1.0 + add / base
    );
    let mut sorted = ratios.clone();
    sorted.sort_by(f64::total_cmp);
    println!(
        "census-refine 640x480, {rounds} rounds x {reps} frames per arm: median frame confidence+mask {:.2} ms, \
         without {:.2} ms; median of the per-round ratios {:.4} (min {:.4}, max {:.4})",
        median(&mut all_on),
        median(&mut all_off),
        median(&mut ratios),
        sorted[0],
        sorted[sorted.len() - 1]
    );
}
