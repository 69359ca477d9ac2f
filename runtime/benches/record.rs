//! Recording: one stereo pair written by `sinks::session_writer` (two 1600x1200 gray PNGs with
//! fast compression + the frames.csv row), against the same images saved with the `image`
//! crate's default PNG settings (the baseline), in the same run (runtime/BENCHMARKS.md).
//! At 25 fps a pair must take well under 40 ms of one core for `abvs record` to keep up.
use abvs_runtime::sinks::session_writer::{CalibFiles, SessionWriter};
use abvs_runtime_core::messages::{Frame, FramePair};
use criterion::{criterion_group, criterion_main, Criterion};

const W: u32 = 1600;
const H: u32 = 1200;

/// A fixture frame (800x600, rendered scene) upscaled 2x: real image statistics at full size.
fn frame(name: &str, t: i64) -> Frame {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/session");
    let small = image::open(dir.join(name)).expect("fixture frame").to_luma8();
    let big = image::imageops::resize(&small, W, H, image::imageops::FilterType::Triangle);
    Frame {
        seq: 0,
        t_start_ns: t,
        exposure_ns: 4_000_000,
        readout_anchor: 0.0,
        width: W,
        height: H,
        gray: big.into_raw(),
    }
}

fn write_pair(c: &mut Criterion) {
    let fixture = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/session/calib");
    let left = frame("frames/left_000010.png", 0);
    let right = frame("frames/right_000010.png", 0);
    let tmp = tempfile::tempdir().unwrap();
    let mut g = c.benchmark_group("record_pair_1600x1200");
    g.sample_size(20);
    let mut writer =
        SessionWriter::create(&tmp.path().join("s"), &CalibFiles::from_dir(&fixture), 25.0, "bench".into())
            .expect("session writer");
    let mut t = 0i64;
    g.bench_function("session_writer_fast_png", |b| {
        b.iter(|| {
            t += 40_000_000;
            let pair = FramePair {
                seq: 0,
                left: Frame { t_start_ns: t, ..left.clone() },
                right: Frame { t_start_ns: t, ..right.clone() },
            };
            writer.write_pair(&pair).unwrap();
        })
    });
    let (l, r) = (
        image::GrayImage::from_raw(W, H, left.gray.clone()).unwrap(),
        image::GrayImage::from_raw(W, H, right.gray.clone()).unwrap(),
    );
    let base = tmp.path().join("baseline");
    std::fs::create_dir_all(&base).unwrap();
    g.bench_function("baseline_image_save_default_png", |b| {
        b.iter(|| {
            l.save(base.join("l.png")).unwrap();
            r.save(base.join("r.png")).unwrap();
        })
    });
    g.finish();
}

criterion_group!(benches, write_pair);
criterion_main!(benches);
