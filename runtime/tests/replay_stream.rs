//! Streaming replay: a session's frames are decoded ahead in a small ring, never all at once, so the replay's
//! memory does not grow with the session's length; a frame file that never finishes reading (a FIFO nobody
//! writes, standing for a hung mount) ends the replay with the reason instead of hanging it.
//!
//! One test function: the live-heap counter below is global, so nothing else may run beside it.
use std::alloc::{GlobalAlloc, Layout, System};
use std::path::Path;
use std::process::Command;
use std::sync::atomic::{AtomicI64, Ordering};
use std::time::{Duration, Instant};

use abvs_runtime::sources::replay::{ReplaySource, RING};
use abvs_runtime_core::session::{EncoderRecord, FrameRecord, Session, SessionMeta, SESSION_FORMAT};

struct Tracking;
/// Bytes allocated and not yet freed (all threads), and the highest value since the last reset.
static LIVE: AtomicI64 = AtomicI64::new(0);
static PEAK: AtomicI64 = AtomicI64::new(0);

fn grow(n: i64) {
    let now = LIVE.fetch_add(n, Ordering::Relaxed) + n;
    PEAK.fetch_max(now, Ordering::Relaxed);
}

unsafe impl GlobalAlloc for Tracking {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        grow(l.size() as i64);
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        LIVE.fetch_sub(l.size() as i64, Ordering::Relaxed);
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        grow(n as i64 - l.size() as i64);
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static A: Tracking = Tracking;

const W: u32 = 160;
const H: u32 = 120;
/// Distinct frame files (rows cycle over them).
const FILES: usize = 8;

/// A session of `rows` frames at 25 fps over `FILES` noise images, encoders at 100 Hz per eye.
fn session(dir: &Path, rows: usize) {
    std::fs::create_dir_all(dir.join("frames")).unwrap();
    let mut state = 0x2545f491u32;
    for i in 0..FILES {
        let img = image::GrayImage::from_fn(W, H, |_, _| {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            image::Luma([state as u8])
        });
        img.save(dir.join(format!("frames/{i}.png"))).unwrap();
    }
    let t0 = 1_000_000_000i64;
    let frames: Vec<FrameRecord> = (0..rows)
        .map(|k| FrameRecord {
            seq: k as u64,
            t_start_ns: t0 + k as i64 * 40_000_000,
            exposure_ns: 4_000_000,
            left: format!("frames/{}.png", k % FILES),
            right: format!("frames/{}.png", (k + 1) % FILES),
        })
        .collect();
    let encoders: Vec<EncoderRecord> = (0..rows * 8)
        .map(|k| EncoderRecord {
            t_ns: t0 - 20_000_000 + k as i64 * 5_000_000,
            eye: (k % 2) as u8,
            count1: 0,
            count2: 0,
            count3: 0,
        })
        .collect();
    let meta = SessionMeta {
        format: SESSION_FORMAT.into(),
        description: format!("{rows} rows over {FILES} noise images"),
        width: W,
        height: H,
        fps: 25.0,
        loop_period_ns: None,
        readout_ms: 0.0,
        exposure_ms: None,
        time_offset_ms: None,
        stereo: "calib/stereo.yaml".into(),
        fk: ["calib/eye0".into(), "calib/eye1".into()],
        gravity: [0.0, 1.0, 0.0],
        truth: None,
    };
    Session::write_index(dir, &meta, &frames, &encoders).unwrap();
}

/// Replays one pass; returns the pairs delivered and the highest heap growth (bytes) from just before
/// `start` to the end of the pass.
fn one_pass(dir: &Path) -> (u64, i64) {
    let mut src = ReplaySource::open(Session::open(dir).unwrap()).unwrap();
    let base = LIVE.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    let _enc = src.start(0);
    let mut n = 0u64;
    let mut sum = 0u64;
    while let Some(f) = src.next_frame(None) {
        sum += f.left[7] as u64 + f.right[(W * H) as usize - 1] as u64;
        n += 1;
    }
    assert!(sum > 0);
    assert_eq!(src.ended, None);
    assert_eq!(src.frames_failed().count(), 0);
    (n, PEAK.load(Ordering::Relaxed) - base)
}

#[test]
fn replay_memory_is_bounded_and_a_stalled_file_ends_it() {
    let d = tempfile::tempdir().unwrap();
    // ---- memory: a 40x longer session replays in the same memory
    let (short, long) = (d.path().join("short"), d.path().join("long"));
    session(&short, 50);
    session(&long, 2000);
    let (n_short, grow_short) = one_pass(&short);
    let (n_long, grow_long) = one_pass(&long);
    let pair = 2 * (W * H) as i64;
    eprintln!(
        "heap growth while replaying: {n_short} rows {grow_short} B, {n_long} rows {grow_long} B \
         (ring {RING} pairs = {} B; all {n_long} pairs decoded would be {} B)",
        RING as i64 * pair,
        n_long as i64 * pair
    );
    assert_eq!((n_short, n_long), (50, 2000));
    // the ring plus the decoder's per-file state, whatever the length
    assert!(grow_long <= grow_short + 64 * 1024, "{grow_long} B for 2000 rows vs {grow_short} B for 50");
    assert!(grow_long < (RING as i64 + 4) * pair + 512 * 1024, "{grow_long} B");

    // ---- a stall: row 5's left file is a FIFO nobody writes (opening it blocks forever)
    let s = d.path().join("stall");
    session(&s, 20);
    let mut frames = std::fs::read_to_string(s.join("frames.csv")).unwrap();
    frames = frames.replacen("frames/5.png,frames/6.png", "frames/fifo.png,frames/6.png", 1);
    std::fs::write(s.join("frames.csv"), frames).unwrap();
    let fifo = s.join("frames/fifo.png");
    assert!(Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    let mut src = ReplaySource::open(Session::open(&s).unwrap()).unwrap();
    src.stall_timeout = Duration::from_millis(400);
    let _enc = src.start(0);
    let t0 = Instant::now();
    let mut seqs = Vec::new();
    while let Some(f) = src.next_frame(Some(100)) {
        seqs.push(f.session_seq);
    }
    let waited = t0.elapsed();
    let why = src.ended.clone().expect("the replay says why it ended");
    eprintln!("stalled replay: {seqs:?} then `{why}` after {waited:?}");
    assert_eq!(seqs, (0..5).collect::<Vec<u64>>());
    assert!(why.contains("stalled") && why.contains("row 5") && why.contains("fifo.png"), "{why}");
    assert!(waited < Duration::from_secs(3), "{waited:?}");
    assert_eq!(src.next_frame(Some(100)).map(|f| f.seq), None, "an ended replay stays ended");
    drop(src);
    // release the decoder blocked in open(): it reads end-of-file, fails to hand over, and exits
    drop(std::fs::OpenOptions::new().write(true).open(&fifo).unwrap());
}
