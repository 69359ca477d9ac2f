//! Reading one eye frame from a session's files, per layout (issue 38, runtime/BENCHMARKS.md "Frame files"):
//! the PNG the replay reads (decoded as `sources::replay` does: the `image` crate's PNG decoder straight into
//! the buffer), raw 8-bit gray, and raw compressed with LZ4 (block format). Each file is read from the page
//! cache every iteration, as the replay's decode-ahead thread does. The frame is the first left frame of
//! `ABVS_BENCH_SESSION` (default: the embedded fixture, 800x600); for the sensor's size render one:
//! `abvs sim session --out S --width 1600 --height 1200`.
use std::io::Read;
use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, Criterion};
use image::ImageDecoder;

fn frame_png() -> PathBuf {
    let session = std::env::var_os("ABVS_BENCH_SESSION")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../fixtures/session"));
    session.join("frames/left_000000.png")
}

fn decode_png(path: &std::path::Path, buf: &mut [u8]) {
    let dec = image::ImageReader::open(path).unwrap().with_guessed_format().unwrap().into_decoder().unwrap();
    assert_eq!(dec.color_type(), image::ColorType::L8, "{}: the sessions' frames are 8-bit gray", path.display());
    dec.read_image(buf).unwrap();
}

fn read_raw(path: &std::path::Path, buf: &mut [u8]) {
    std::fs::File::open(path).unwrap().read_exact(buf).unwrap();
}

fn layouts(c: &mut Criterion) {
    let png = frame_png();
    let img = image::open(&png).unwrap_or_else(|e| panic!("{}: {e}", png.display())).into_luma8();
    let (w, h) = img.dimensions();
    let dir = tempfile::tempdir().unwrap();
    let (raw, lz4) = (dir.path().join("left.gray"), dir.path().join("left.gray.lz4"));
    std::fs::write(&raw, img.as_raw()).unwrap();
    std::fs::write(&lz4, lz4_flex::block::compress(img.as_raw())).unwrap();
    let size = |p: &std::path::Path| std::fs::metadata(p).unwrap().len() as f64 / 1e6;
    eprintln!(
        "{}: {w}x{h}; files: png {:.2} MB, raw {:.2} MB, lz4 {:.2} MB",
        png.display(),
        size(&png),
        size(&raw),
        size(&lz4)
    );
    let mut buf = vec![0u8; (w * h) as usize];
    let mut packed = Vec::new();
    let mut g = c.benchmark_group(format!("frame_file_{w}x{h}"));
    g.sample_size(30);
    g.bench_function("png", |b| b.iter(|| decode_png(&png, &mut buf)));
    g.bench_function("raw", |b| b.iter(|| read_raw(&raw, &mut buf)));
    g.bench_function("lz4", |b| {
        b.iter(|| {
            packed.clear();
            std::fs::File::open(&lz4).unwrap().read_to_end(&mut packed).unwrap();
            lz4_flex::block::decompress_into(&packed, &mut buf).unwrap();
        })
    });
    g.finish();
    assert_eq!(buf, *img.as_raw(), "every layout reads back the same frame");
}

criterion_group!(benches, layouts);
criterion_main!(benches);
