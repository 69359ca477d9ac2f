//! iceoryx2 bridge benchmarks: `cargo bench -p abvs-runtime --bench bridge`.
//! Publish of a depth map / point cloud (the caller's fill copies a prepared frame into the loaned shared
//! memory; one subscriber attached that never reads), and the in-process round trip publish -> wait.
//! Medians: target/criterion/bridge_*/**/new/estimates.json; written up in runtime/BENCHMARKS.md.
use std::time::Duration;

use abvs_runtime::bridges::iceoryx::*;
use abvs_runtime_core::messages::monotonic_ns;
use criterion::{criterion_group, criterion_main, Criterion};

fn header(seq: u64, w: u32, h: u32) -> FrameHeader {
    let mut hd = FrameHeader::new_left_home();
    hd.seq = seq;
    hd.t_frame_ns = monotonic_ns();
    hd.width = w;
    hd.height = h;
    hd
}

fn copy_into<T: Copy>(dst: &mut SampleWriter<'_, T>, src: &[T]) {
    dst.extend_from_slice(src)
}

fn cloud_frame(n: usize) -> Vec<CloudPoint> {
    (0..n).map(|i| CloudPoint { x: i as f32 * 1e-3, y: -(i as f32) * 1e-3, z: 1.5, rgba: i as u32 }).collect()
}

fn bench(c: &mut Criterion) {
    let pid = std::process::id();
    // the fixed cost of a sample (loan, header, send, notify / wake-up), without the payload copy
    {
        let cfg = BridgeConfig::for_resolution(16, 16).with_prefix(format!("abvs-bench-{pid}-1pt"));
        let mut cp = CloudPublisher::new(&cfg).unwrap();
        let mut cs = CloudSubscriber::new(&cfg).unwrap();
        let mut seq = 0u64;
        let one = [CloudPoint { x: 0.0, y: 0.0, z: 1.0, rgba: 0 }];
        let mut g = c.benchmark_group("bridge_overhead");
        g.sample_size(30).measurement_time(Duration::from_secs(3)).warm_up_time(Duration::from_millis(500));
        g.bench_function("publish_cloud_1pt", |b| {
            b.iter(|| {
                seq += 1;
                cp.publish_cloud(&header(seq, 16, 16), 1, |p| copy_into(p, &one)).unwrap()
            })
        });
        while cs.try_receive().unwrap().is_some() {}
        g.bench_function("round_trip_cloud_1pt", |b| {
            b.iter(|| {
                seq += 1;
                cp.publish_cloud(&header(seq, 16, 16), 1, |p| copy_into(p, &one)).unwrap();
                cs.wait(Duration::from_secs(1)).unwrap().unwrap();
            })
        });
        g.finish();
    }
    for (w, h) in [(320u32, 240u32), (640, 480)] {
        let n = (w * h) as usize;
        let cfg = BridgeConfig::for_resolution(w, h).with_prefix(format!("abvs-bench-{pid}-{w}"));
        let mut dp = DepthPublisher::new(&cfg).unwrap();
        let mut cp = CloudPublisher::new(&cfg).unwrap();
        let _idle_d = DepthSubscriber::new(&cfg).unwrap();
        let _idle_c = CloudSubscriber::new(&cfg).unwrap();
        let depth: Vec<f32> = (0..n).map(|i| 0.5 + i as f32 * 1e-6).collect();
        let cloud = cloud_frame(n);
        let mut seq = 0u64;

        let mut g = c.benchmark_group("bridge_publish");
        g.sample_size(30).measurement_time(Duration::from_secs(3)).warm_up_time(Duration::from_millis(500));
        g.bench_function(format!("depth_{w}x{h}"), |b| {
            b.iter(|| {
                seq += 1;
                dp.publish_depth(&header(seq, w, h), |d| copy_into(d, &depth)).unwrap()
            })
        });
        g.bench_function(format!("cloud_{w}x{h}_{n}pts"), |b| {
            b.iter(|| {
                seq += 1;
                cp.publish_cloud(&header(seq, w, h), n, |p| copy_into(p, &cloud)).unwrap()
            })
        });
        g.finish();

        // round trip in one process: publish, then the subscriber's wait returns it
        let rt = cfg.clone().with_prefix(format!("abvs-bench-rt-{pid}-{w}"));
        let mut cp = CloudPublisher::new(&rt).unwrap();
        let mut cs = CloudSubscriber::new(&rt).unwrap();
        let mut dp = DepthPublisher::new(&rt).unwrap();
        let mut ds = DepthSubscriber::new(&rt).unwrap();
        let mut g = c.benchmark_group("bridge_round_trip");
        g.sample_size(30).measurement_time(Duration::from_secs(3)).warm_up_time(Duration::from_millis(500));
        g.bench_function(format!("depth_{w}x{h}"), |b| {
            b.iter(|| {
                seq += 1;
                dp.publish_depth(&header(seq, w, h), |d| copy_into(d, &depth)).unwrap();
                let r = ds.wait(Duration::from_secs(1)).unwrap().unwrap();
                assert_eq!(r.header().seq, seq);
            })
        });
        g.bench_function(format!("cloud_{w}x{h}_{n}pts"), |b| {
            b.iter(|| {
                seq += 1;
                cp.publish_cloud(&header(seq, w, h), n, |p| copy_into(p, &cloud)).unwrap();
                let r = cs.wait(Duration::from_secs(1)).unwrap().unwrap();
                assert_eq!(r.data().len(), n);
            })
        });
        g.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
