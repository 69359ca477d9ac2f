//! Steady-state publishing allocates nothing of ours: a counting global allocator around publish_depth /
//! publish_cloud (with subscribers attached, one of them reading).
//!
//! iceoryx2 0.10 itself allocates exactly one small block per loan (`SampleMutUninit::new` puts the
//! sample's shared state in an `Arc`, ~104 bytes, freed at send); no public API avoids it. The test allows
//! that one and nothing else, so any Vec/String/format! added to the publish path fails it.
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use abvs_runtime::bridges::iceoryx::*;
use abvs_runtime_core::messages::monotonic_ns;

struct Counting;
static ALLOCS: AtomicU64 = AtomicU64::new(0);
static MAX_SIZE: AtomicU64 = AtomicU64::new(0);
thread_local! { static COUNT_HERE: Cell<bool> = const { Cell::new(false) }; }

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        if COUNT_HERE.with(|c| c.get()) {
            MAX_SIZE.fetch_max(l.size() as u64, Ordering::Relaxed);
            if ALLOCS.fetch_add(1, Ordering::Relaxed) == 0 && std::env::var_os("ABVS_ALLOC_TRACE").is_some() {
                COUNT_HERE.with(|c| c.set(false));
                eprintln!("first allocation ({l:?}):\n{}", std::backtrace::Backtrace::force_capture());
                COUNT_HERE.with(|c| c.set(true));
            }
        }
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        if COUNT_HERE.with(|c| c.get()) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
            MAX_SIZE.fetch_max(n as u64, Ordering::Relaxed);
        }
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn publish_allocates_nothing_in_steady_state() {
    let cfg = BridgeConfig::for_resolution(64, 48).with_prefix(format!("abvs-alloc-{}", std::process::id()));
    let mut dp = DepthPublisher::new(&cfg).unwrap();
    let mut cp = CloudPublisher::new(&cfg).unwrap();
    let _idle = CloudSubscriber::new(&cfg).unwrap();
    let mut reader = DepthSubscriber::new(&cfg).unwrap();
    let mut h = FrameHeader::new_left_home();
    (h.width, h.height) = (64, 48);
    let mut publish = |seq: u64| {
        h.seq = seq;
        h.t_frame_ns = monotonic_ns();
        dp.publish_depth(&h, |d| {
            for _ in 0..d.capacity() {
                d.push(1.0);
            }
        })
        .unwrap();
        cp.publish_cloud(&h, 100, |p| {
            for _ in 0..90 {
                p.push(CloudPoint { x: 0.0, y: 0.0, z: 1.0, rgba: 0 });
            }
        })
        .unwrap();
    };
    // warm-up: connections established, the history queue filled
    for seq in 0..10 {
        publish(seq);
        while reader.try_receive().unwrap().is_some() {}
    }
    COUNT_HERE.with(|c| c.set(true));
    for seq in 10..200 {
        publish(seq);
    }
    COUNT_HERE.with(|c| c.set(false));
    let n = ALLOCS.load(Ordering::Relaxed);
    let max = MAX_SIZE.load(Ordering::Relaxed);
    // 190 x (depth + cloud) publishes: one iceoryx2 loan block each, nothing else
    assert!(n <= 380, "{n} heap allocations in 380 steady-state publishes (iceoryx2's loan accounts for 380)");
    assert!(
        max <= 128,
        "an allocation of {max} bytes in the publish path: only iceoryx2's small loan block is expected"
    );
    assert!(reader.wait(Duration::from_secs(1)).unwrap().is_some());
}
