//! Buffer -> gray conversion of one 1600x1200 eye frame, per V4L2 layout (runtime/BENCHMARKS.md).
use abvs_runtime::sources::pixel::{Bayer10Packing, GrayConverter, PixelFormat};
use criterion::{criterion_group, criterion_main, Criterion};

const W: u32 = 1600;
const H: u32 = 1200;

fn conversions(c: &mut Criterion) {
    let mut g = c.benchmark_group("to_gray_1600x1200");
    g.sample_size(30);
    let mut out = vec![0u8; (W * H) as usize];
    for fmt in PixelFormat::ALL {
        // One representative CFA order per packing: the order only changes which gains apply.
        if let PixelFormat::Bayer10 { order, .. } = fmt {
            if order != abvs_runtime::sources::pixel::CfaOrder::Grbg {
                continue;
            }
        }
        let stride = fmt.min_bytesperline(W);
        let len = match fmt {
            PixelFormat::Nv12 => stride * H as usize * 3 / 2,
            _ => stride * H as usize,
        };
        let src: Vec<u8> = (0..len).map(|i| (i.wrapping_mul(2654435761) >> 13) as u8).collect();
        let mut conv = GrayConverter::new(fmt, W, H, stride, 64).unwrap();
        let name = match fmt {
            PixelFormat::Yuyv => "yuyv".to_string(),
            PixelFormat::Nv12 => "nv12".to_string(),
            PixelFormat::Bayer10 { packing: Bayer10Packing::Unpacked16Le, .. } => "bayer10_unpacked16".to_string(),
            PixelFormat::Bayer10 { packing: Bayer10Packing::MipiPacked, .. } => "bayer10_mipi_packed".to_string(),
        };
        g.bench_function(name, |b| b.iter(|| conv.convert(std::hint::black_box(&src), &mut out).unwrap()));
    }
    g.finish();
}

criterion_group!(benches, conversions);
criterion_main!(benches);
