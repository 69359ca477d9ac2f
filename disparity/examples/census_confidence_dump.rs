//! census-refine's internals at 640x480 as raw files, the input of scripts/fit_census_confidence.py (which
//! fitted the weights of disparity/src/census_confidence.rs):
//! `cargo run -p abvs-disparity --example census_confidence_dump -- LEFT RIGHT OUTDIR`. The pair is resampled
//! as `abvs disparity-eval --resolution 640x480` does (INTER_AREA); the engine is the runtime's default
//! (hitnet-m's refine base, hitnet-s, with the SGBM prior at 320x240).
use abvs_disparity::census::CensusRefineEngine;
use abvs_disparity::engine::{set_opencv_threads, DisparityEngine};
use abvs_disparity::onnx::OnnxEngine;
use opencv::core::{Mat, Size};
use opencv::prelude::*;
use opencv::{imgcodecs, imgproc};
use std::io::Write;

fn load(p: &str, mode: i32) -> Mat {
    imgcodecs::imread(p, mode).unwrap()
}
fn resize(m: &Mat, w: i32, h: i32) -> Vec<u8> {
    let mut r = Mat::default();
    imgproc::resize(m, &mut r, Size::new(w, h), 0.0, 0.0, imgproc::INTER_AREA).unwrap();
    r.data_bytes().unwrap().to_vec()
}
fn put<T: Copy>(dir: &str, name: &str, v: &[T]) {
    // SAFETY: plain numbers (u8 / f32), read as their bytes
    let b = unsafe { std::slice::from_raw_parts(v.as_ptr() as *const u8, std::mem::size_of_val(v)) };
    std::fs::File::create(format!("{dir}/{name}")).unwrap().write_all(b).unwrap();
}
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let (l, r, out) = (&a[1], &a[2], &a[3]);
    std::fs::create_dir_all(out).unwrap();
    set_opencv_threads(2).unwrap();
    let (w, h) = (640u32, 480u32);
    let lb = resize(&load(l, imgcodecs::IMREAD_GRAYSCALE), w as i32, h as i32);
    let rb = resize(&load(r, imgcodecs::IMREAD_GRAYSCALE), w as i32, h as i32);
    let models = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/hitnet/hitnet-m");
    let base = abvs_disparity::manifest::refine_base(&models).unwrap();
    let mut e = CensusRefineEngine::new(OnnxEngine::load(&base, 2).unwrap(), w, h).unwrap();
    let mut d = vec![0f32; (w * h) as usize];
    e.compute(&lb, &rb, &mut d).unwrap();
    let (c, why) = e.confidence().unwrap();
    put(out, "left640.u8", &lb);
    put(out, "right640.u8", &rb);
    put(out, "out640.f32", &d);
    put(out, "conf640.f32", c);
    put(out, "why640.u8", why);
    put(out, "cost.f32", e.match_cost());
    put(out, "curv.f32", e.match_curvature());
    let (nl, nr, st, re, net, pr) = e.internals().unwrap();
    put(out, "left.u8", nl);
    put(out, "right.u8", nr);
    put(out, "stat.u8", st);
    put(out, "refined.f32", re);
    put(out, "net.f32", net);
    put(out, "prior.f32", pr);
    eprintln!("{} done", e.name());
}
