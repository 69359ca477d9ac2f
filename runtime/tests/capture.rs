//! Camera capture without cameras: pixel conversion against a reference, pairing under random drops
//! and jitter, the device-free parts of V4L2 capture, the capture threads on stand-in sources, and
//! the clear errors for missing devices.
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::time::Duration;

use abvs_runtime::sources::pairing::{Pairer, PairerConfig, Side};
use abvs_runtime::sources::pixel::{Bayer10Packing, CfaOrder, GrayConverter, PixelError, PixelFormat};
use abvs_runtime::sources::v4l_capture::*;
use abvs_runtime_core::messages::{Frame, FramePair};
use proptest::prelude::*;

// ---------------------------------------------------------------- allocation counting (per thread)

struct Counting;

thread_local! {
    static ALLOCS: Cell<u64> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
        System.alloc(layout)
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout)
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let _ = ALLOCS.try_with(|c| c.set(c.get() + 1));
        System.realloc(ptr, layout, new_size)
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocs() -> u64 {
    ALLOCS.with(|c| c.get())
}

// ---------------------------------------------------------------- synthetic buffers

/// A deterministic pseudo-random 10-bit mosaic.
fn mosaic(w: usize, h: usize, seed: u64) -> Vec<u16> {
    let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    (0..w * h)
        .map(|_| {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((s >> 33) % 1024) as u16
        })
        .collect()
}

fn pack16(px: &[u16], w: usize, h: usize, stride: usize) -> Vec<u8> {
    let mut buf = vec![0xee; stride * h];
    for y in 0..h {
        for x in 0..w {
            // High bits set to garbage: the converter must mask to 10 bits.
            let v = px[y * w + x] | 0xfc00;
            buf[y * stride + 2 * x..y * stride + 2 * x + 2].copy_from_slice(&v.to_le_bytes());
        }
    }
    buf
}

fn pack10p(px: &[u16], w: usize, h: usize, stride: usize) -> Vec<u8> {
    let mut buf = vec![0xee; stride * h];
    for y in 0..h {
        for g in 0..w / 4 {
            let p = &px[y * w + 4 * g..y * w + 4 * g + 4];
            let o = &mut buf[y * stride + 5 * g..y * stride + 5 * g + 5];
            for i in 0..4 {
                o[i] = (p[i] >> 2) as u8;
            }
            o[4] = (p[0] & 3) as u8 | ((p[1] & 3) << 2) as u8 | ((p[2] & 3) << 4) as u8 | ((p[3] & 3) << 6) as u8;
        }
    }
    buf
}

const ORDERS: [CfaOrder; 4] = [CfaOrder::Bggr, CfaOrder::Gbrg, CfaOrder::Grbg, CfaOrder::Rggb];

/// Colour (0 R, 1 G, 2 B) at (x, y) for a CFA order.
fn colour(order: CfaOrder, x: usize, y: usize) -> usize {
    let sites = match order {
        CfaOrder::Bggr => [[2, 1], [1, 0]],
        CfaOrder::Gbrg => [[1, 2], [0, 1]],
        CfaOrder::Grbg => [[1, 0], [2, 1]],
        CfaOrder::Rggb => [[0, 1], [1, 2]],
    };
    sites[y % 2][x % 2]
}

/// The documented definition, in floating point: the mean of the luma of the four 2x2 windows
/// containing the pixel (windows clamped to the image), then the black level and `>> 2`.
fn reference_luma(px: &[u16], w: usize, h: usize, order: CfaOrder, black: f64) -> Vec<f64> {
    let window = |wx: usize, wy: usize| {
        let mut rgb = [0.0; 3];
        for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            let (x, y) = (wx + dx, wy + dy);
            let c = colour(order, x, y);
            rgb[c] += f64::from(px[y * w + x]) * if c == 1 { 0.5 } else { 1.0 };
        }
        0.299 * rgb[0] + 0.587 * rgb[1] + 0.114 * rgb[2]
    };
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for wy in [y.saturating_sub(1), y.min(h - 2)] {
                for wx in [x.saturating_sub(1), x.min(w - 2)] {
                    s += window(wx, wy);
                }
            }
            let v = s / 4.0;
            out[y * w + x] = ((v - black).max(0.0) * 256.0 / (1024.0 - black)).min(255.0);
        }
    }
    out
}

// ---------------------------------------------------------------- pixel.rs

#[test]
fn yuyv_and_nv12_take_the_y_plane_honouring_the_stride() {
    // 6: remainder only; 40: two 16-pixel blocks and a remainder.
    for (w, h, stride) in [(6usize, 4usize, 16usize), (40, 4, 96)] {
        y_plane_case(w, h, stride);
    }
}

fn y_plane_case(w: usize, h: usize, stride: usize) {
    let mut yuyv = vec![0u8; stride * h];
    let mut nv12 = vec![0u8; stride * h + stride * h / 2];
    let mut want = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let v = (y * 40 + x * 7 + x / 16) as u8;
            want.push(v);
            yuyv[y * stride + 2 * x] = v;
            yuyv[y * stride + 2 * x + 1] = 200; // chroma, ignored
            nv12[y * stride + x] = v;
        }
        for pad in 2 * w..stride {
            yuyv[y * stride + pad] = 99;
        }
    }
    let mut out = vec![0u8; w * h];
    GrayConverter::new(PixelFormat::Yuyv, w as u32, h as u32, stride, 0).unwrap().convert(&yuyv, &mut out).unwrap();
    assert_eq!(out, want);
    out.fill(0);
    // NV12 only needs the Y plane, and only the pixels of the last row.
    let need = stride * (h - 1) + w;
    GrayConverter::new(PixelFormat::Nv12, w as u32, h as u32, stride, 0)
        .unwrap()
        .convert(&nv12[..need], &mut out)
        .unwrap();
    assert_eq!(out, want);
}

#[test]
fn bayer_matches_the_documented_reference_for_all_orders_and_layouts() {
    let (w, h) = (12usize, 8usize);
    let px = mosaic(w, h, 7);
    for order in ORDERS {
        for black in [0u16, 64] {
            let want = reference_luma(&px, w, h, order, f64::from(black));
            for (packing, stride) in
                [(Bayer10Packing::Unpacked16Le, 2 * w + 8), (Bayer10Packing::MipiPacked, 5 * w / 4 + 3)]
            {
                let buf = match packing {
                    Bayer10Packing::Unpacked16Le => pack16(&px, w, h, stride),
                    Bayer10Packing::MipiPacked => pack10p(&px, w, h, stride),
                };
                let mut c =
                    GrayConverter::new(PixelFormat::Bayer10 { order, packing }, w as u32, h as u32, stride, black)
                        .unwrap();
                let mut out = vec![0u8; w * h];
                c.convert(&buf, &mut out).unwrap();
                for (i, (&o, &r)) in out.iter().zip(&want).enumerate() {
                    // Fixed-point gains and rounding, then truncation by the shift.
                    assert!(
                        (f64::from(o) - r).abs() <= 1.5,
                        "{order:?} {packing:?} black {black} at ({}, {}): {o} vs {r:.2}",
                        i % w,
                        i / w
                    );
                }
            }
        }
    }
}

#[test]
fn bayer_flat_fields_and_pure_colours() {
    let (w, h) = (8usize, 6usize);
    for order in ORDERS {
        let fmt = PixelFormat::Bayer10 { order, packing: Bayer10Packing::Unpacked16Le };
        let mut c = GrayConverter::new(fmt, w as u32, h as u32, 2 * w, 0).unwrap();
        let mut out = vec![0u8; w * h];
        for v in [0u16, 1, 4, 511, 1023] {
            let buf = pack16(&vec![v; w * h], w, h, 2 * w);
            c.convert(&buf, &mut out).unwrap();
            assert!(out.iter().all(|&o| o == (v >> 2) as u8), "{order:?} flat {v}: {out:?}");
        }
        // A saturated single colour (everywhere, borders included) gives that colour's luma weight.
        for (col, weight) in [(0, 0.299), (1, 0.587), (2, 0.114)] {
            let px: Vec<u16> = (0..w * h).map(|i| if colour(order, i % w, i / w) == col { 1023 } else { 0 }).collect();
            c.convert(&pack16(&px, w, h, 2 * w), &mut out).unwrap();
            let want = weight * 1023.0 / 4.0;
            assert!(out.iter().all(|&o| (f64::from(o) - want).abs() <= 1.0), "{order:?} colour {col}: {out:?}");
        }
    }
    // The black level goes to 0 and white stays white.
    let fmt = PixelFormat::Bayer10 { order: CfaOrder::Grbg, packing: Bayer10Packing::MipiPacked };
    let mut c = GrayConverter::new(fmt, 8, 2, 10, 64).unwrap();
    let mut out = [0u8; 16];
    c.convert(&pack10p(&[64; 16], 8, 2, 10), &mut out).unwrap();
    assert_eq!(out, [0; 16]);
    c.convert(&pack10p(&[1023; 16], 8, 2, 10), &mut out).unwrap();
    assert_eq!(out, [255; 16]);
}

#[test]
fn conversion_errors_say_expected_and_got() {
    let fmt = PixelFormat::Bayer10 { order: CfaOrder::Bggr, packing: Bayer10Packing::Unpacked16Le };
    let mut c = GrayConverter::new(fmt, 1600, 1200, 3200, 0).unwrap();
    let mut out = vec![0u8; 1600 * 1200];
    let e = c.convert(&vec![0u8; 1000], &mut out).unwrap_err();
    assert_eq!(
        e,
        PixelError::SrcTooShort {
            format: "BG10".into(),
            width: 1600,
            height: 1200,
            stride: 3200,
            expected: 3200 * 1200,
            got: 1000
        }
    );
    let msg = e.to_string();
    assert!(msg.contains("expected at least 3840000 bytes, got 1000") && msg.contains("BG10"), "{msg}");

    let e = c.convert(&vec![0u8; 3200 * 1200], &mut [0u8; 10]).unwrap_err();
    assert!(e.to_string().contains("expected 1920000 bytes (1600x1200), got 10"), "{e}");

    let e = PixelFormat::from_fourcc(*b"MJPG").unwrap_err();
    assert!(e.to_string().contains("'MJPG'") && e.to_string().contains("YUYV"), "{e}");
    let e = PixelFormat::from_fourcc([0x01, b'A', b'B', b'C']).unwrap_err();
    assert!(e.to_string().contains("\\x01ABC"), "{e}");

    let e = GrayConverter::new(PixelFormat::Yuyv, 1600, 1200, 3000, 0).unwrap_err();
    assert!(e.to_string().contains("bytesperline 3000 is below the minimum 3200"), "{e}");
    let packed = PixelFormat::Bayer10 { order: CfaOrder::Rggb, packing: Bayer10Packing::MipiPacked };
    assert!(GrayConverter::new(packed, 1602, 1200, 4000, 0).is_err());
    assert!(GrayConverter::new(packed, 1600, 1200, 2000, 257).is_err());
    assert_eq!(packed.min_bytesperline(1600), 2000);
}

#[test]
fn conversion_does_not_allocate() {
    let (w, h) = (1600usize, 1200usize);
    let px = mosaic(w, h, 3);
    let mut out = vec![0u8; w * h];
    for fmt in PixelFormat::ALL {
        let stride = fmt.min_bytesperline(w as u32) + 64;
        let buf = match fmt {
            PixelFormat::Bayer10 { packing: Bayer10Packing::Unpacked16Le, .. } => pack16(&px, w, h, stride),
            PixelFormat::Bayer10 { packing: Bayer10Packing::MipiPacked, .. } => pack10p(&px, w, h, stride),
            _ => vec![128u8; stride * h * 2],
        };
        let mut c = GrayConverter::new(fmt, w as u32, h as u32, stride, 64).unwrap();
        let before = allocs();
        c.convert(&buf, &mut out).unwrap();
        c.convert(&buf, &mut out).unwrap();
        assert_eq!(allocs() - before, 0, "{fmt:?} allocated");
    }
}

// ---------------------------------------------------------------- pairing.rs

fn frame(seq: u64, t_start_ns: i64) -> Frame {
    Frame { seq, t_start_ns, exposure_ns: 5_000_000, readout_anchor: 0.0, width: 0, height: 0, gray: Vec::new() }
}

const PERIOD: i64 = 40_000_000;

#[derive(Clone, Debug)]
struct Slot {
    present: [bool; 2],
    jitter: [i64; 2],
}

/// Runs a pairer over two streams merged in the order `picks` gives (true: left next), checking
/// the invariants after every step; returns the pairs.
fn run(cfg: PairerConfig, streams: [Vec<Frame>; 2], picks: &[bool]) -> (Vec<FramePair>, Pairer) {
    let mut p = Pairer::new(cfg);
    let mut its = streams.map(|s| s.into_iter());
    let mut pairs = Vec::new();
    let mut pick = picks.iter().cycle();
    let mut done = [false; 2];
    while !(done[0] && done[1]) {
        let left_next = done[1] || (!done[0] && *pick.next().unwrap_or(&true));
        let s = usize::from(!left_next);
        match its[s].next() {
            Some(f) => pairs.extend(p.push(if s == 0 { Side::Left } else { Side::Right }, f)),
            None => done[s] = true,
        }
        assert!(p.pending() <= cfg.window.max(1), "pending {} > window", p.pending());
    }
    p.flush();
    (pairs, p)
}

fn check_pairs(pairs: &[FramePair], p: &Pairer, tol: i64) {
    for (i, pair) in pairs.iter().enumerate() {
        assert_eq!(pair.seq, i as u64);
        let dt = (i128::from(pair.left.t_start_ns) - i128::from(pair.right.t_start_ns)).abs();
        assert!(dt <= i128::from(tol), "pair {i}: |dt| {dt} > {tol}");
    }
    for w in pairs.windows(2) {
        assert!(w[1].left.t_start_ns > w[0].left.t_start_ns && w[1].right.t_start_ns > w[0].right.t_start_ns);
    }
    let s = p.stats();
    assert_eq!(s.delivered, pairs.len() as u64);
    assert_eq!(p.pending(), 0);
    assert_eq!(2 * s.delivered + s.discarded(), s.input[0] + s.input[1], "{s:?}");
}

fn slots(tol: i64) -> impl Strategy<Value = Vec<Slot>> {
    let half = tol / 2;
    prop::collection::vec(
        (prop::bool::weighted(0.85), prop::bool::weighted(0.85), -half..=half, -half..=half)
            .prop_map(|(l, r, jl, jr)| Slot { present: [l, r], jitter: [jl, jr] }),
        0..120,
    )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    /// Random drops on both sides and jitter within the tolerance, any interleaving, no window
    /// pressure: exactly the slots both cameras delivered are paired, and the drops are counted.
    #[test]
    fn pairs_every_common_frame(
        tol in 100_000i64..5_000_000,
        slots in slots(2_000_000),
        picks in prop::collection::vec(any::<bool>(), 1..64),
        offset in 0u64..1000,
    ) {
        let tol = tol.max(2_000_000);
        let streams: [Vec<Frame>; 2] = [0, 1].map(|s| {
            slots.iter().enumerate().filter(|(_, sl)| sl.present[s])
                .map(|(i, sl)| frame(i as u64 + offset * s as u64, 1_000_000_000 + i as i64 * PERIOD + sl.jitter[s]))
                .collect()
        });
        let cfg = PairerConfig { tolerance_ns: tol, window: 1000 };
        let (pairs, p) = run(cfg, streams.clone(), &picks);
        check_pairs(&pairs, &p, tol);
        let both = slots.iter().filter(|s| s.present[0] && s.present[1]).count();
        prop_assert_eq!(pairs.len(), both);
        for pair in &pairs {
            prop_assert_eq!(pair.left.seq + offset, pair.right.seq);
        }
        for (s, stream) in streams.iter().enumerate() {
            let seqs: Vec<u64> = stream.iter().map(|f| f.seq).collect();
            let gaps = match (seqs.first(), seqs.last()) {
                (Some(a), Some(b)) => b - a + 1 - seqs.len() as u64,
                _ => 0,
            };
            prop_assert_eq!(p.stats().dropped[s], gaps);
        }
    }

    /// The same with a small window, out-of-order glitches and jitter beyond the tolerance: the
    /// invariants hold (tolerance, increasing pairs, bounded memory, counts add up).
    #[test]
    fn invariants_under_glitches(
        tol in 0i64..5_000_000,
        slots in slots(6_000_000),
        glitches in prop::collection::vec((0usize..120, 0usize..2, -100_000_000i64..100_000_000), 0..10),
        picks in prop::collection::vec(any::<bool>(), 1..64),
        window in 0usize..6,
    ) {
        let mut streams: [Vec<Frame>; 2] = [0, 1].map(|s| {
            slots.iter().enumerate().filter(|(_, sl)| sl.present[s])
                .map(|(i, sl)| frame(i as u64, i as i64 * PERIOD + sl.jitter[s]))
                .collect()
        });
        for (at, s, dt) in glitches {
            if let Some(f) = streams[s].get_mut(at) {
                f.t_start_ns += dt;
                if dt % 3 == 0 { f.seq = f.seq.saturating_sub(2); }
            }
        }
        let (pairs, p) = run(PairerConfig { tolerance_ns: tol, window }, streams, &picks);
        check_pairs(&pairs, &p, tol.max(0));
    }

    /// Arbitrary frames (extreme timestamps and sequence numbers): never a panic, invariants hold.
    #[test]
    fn never_panics(
        input in prop::collection::vec((any::<bool>(), any::<u64>(), any::<i64>()), 0..200),
        tol in any::<i64>(),
        window in 0usize..8,
    ) {
        let mut p = Pairer::new(PairerConfig { tolerance_ns: tol, window });
        let mut pairs = Vec::new();
        for (left, seq, t) in input {
            pairs.extend(p.push(if left { Side::Left } else { Side::Right }, frame(seq, t)));
        }
        p.flush();
        check_pairs(&pairs, &p, tol.max(0));
    }
}

#[test]
fn pairing_does_not_allocate_in_steady_state() {
    let mut p = Pairer::new(PairerConfig::default());
    let mut frames: Vec<(Side, Frame)> = Vec::new();
    for i in 0..100 {
        // Right lags left by two frames, one left frame in ten is lost.
        if i % 10 != 3 {
            frames.push((Side::Left, frame(i, i as i64 * PERIOD)));
        }
        if i >= 2 {
            frames.push((Side::Right, frame(i - 2, (i as i64 - 2) * PERIOD + 300_000)));
        }
    }
    let before = allocs();
    let mut n = 0;
    for (side, f) in frames {
        n += usize::from(p.push(side, f).is_some());
    }
    assert_eq!(allocs() - before, 0);
    assert_eq!(n, 98 - 10); // right frames 0..=97, minus the 10 whose left partner was lost
}

// ---------------------------------------------------------------- v4l_capture.rs, device-free

#[test]
fn timestamp_flags_and_conversion() {
    let mono = BUF_FLAG_TIMESTAMP_MONOTONIC;
    assert_eq!(timestamp_source(mono | BUF_FLAG_TSTAMP_SRC_SOE), Ok(TimestampSource::StartOfExposure));
    assert_eq!(timestamp_source(mono), Ok(TimestampSource::EndOfFrame));
    // Flags outside the two masks do not matter.
    assert_eq!(timestamp_source(mono | BUF_FLAG_ERROR | 0x1), Ok(TimestampSource::EndOfFrame));
    assert!(timestamp_source(BUF_FLAG_TIMESTAMP_UNKNOWN | BUF_FLAG_TSTAMP_SRC_SOE).unwrap_err().contains("unknown"));
    assert!(timestamp_source(BUF_FLAG_TIMESTAMP_COPY).unwrap_err().contains("copied"));
    assert!(timestamp_source(0x6000).is_err());

    assert_eq!(timeval_to_ns(12, 345_678), 12_345_678_000);
    assert_eq!(timeval_to_ns(0, 0), 0);
    assert_eq!(timeval_to_ns(i64::MAX, 999_999), i64::MAX);

    let (exp, ro) = (8_000_000, 30_000_000);
    let soe = TimestampSource::StartOfExposure;
    let eof = TimestampSource::EndOfFrame;
    assert_eq!(start_of_exposure_ns(1_000_000_000, soe, exp, ro, RowReference::FirstRow), 1_000_000_000);
    assert_eq!(start_of_exposure_ns(1_038_000_000, eof, exp, ro, RowReference::FirstRow), 1_000_000_000);
    assert_eq!(start_of_exposure_ns(1_038_000_000, eof, exp, ro, RowReference::CentreRow), 1_015_000_000);
    assert_eq!(start_of_exposure_ns(1_000_000_000, soe, exp, ro, RowReference::CentreRow), 1_015_000_000);
    assert_eq!(start_of_exposure_ns(i64::MIN + 5, eof, exp, ro, RowReference::FirstRow), i64::MIN);
}

fn negotiated(w: u32, h: u32, fourcc: &[u8; 4], bpl: u32, size: u32) -> NegotiatedFormat {
    NegotiatedFormat { width: w, height: h, fourcc: *fourcc, bytesperline: bpl, sizeimage: size }
}

#[test]
fn format_negotiation_is_validated() {
    let cfg = CaptureConfig::default();
    let packed = PixelFormat::Bayer10 { order: CfaOrder::Grbg, packing: Bayer10Packing::MipiPacked };
    assert_eq!(validate_format(&cfg, &negotiated(1600, 1200, b"pgAA", 2000, 2_400_000)), Ok(packed));
    // A padded stride is fine; another supported format is used.
    assert_eq!(validate_format(&cfg, &negotiated(1600, 1200, b"pgAA", 2048, 2048 * 1200)), Ok(packed));
    assert_eq!(validate_format(&cfg, &negotiated(1600, 1200, b"YUYV", 3200, 3_840_000)), Ok(PixelFormat::Yuyv));
    let e = validate_format(&cfg, &negotiated(1600, 1200, b"MJPG", 0, 500_000)).unwrap_err();
    assert!(e.contains("the driver set 1600x1200 MJPG") && e.contains("unsupported pixel format"), "{e}");
    let e = validate_format(&cfg, &negotiated(1280, 720, b"pgAA", 1600, 1_152_000)).unwrap_err();
    assert!(e.contains("asked for 1600x1200 pgAA, the driver set 1280x720 pgAA"), "{e}");
    let e = validate_format(&cfg, &negotiated(1600, 1200, b"pgAA", 1999, 2_400_000)).unwrap_err();
    assert!(e.contains("bytesperline 1999 is below the minimum 2000"), "{e}");
    let e = validate_format(&cfg, &negotiated(1600, 1200, b"pgAA", 2000, 1_000)).unwrap_err();
    assert!(e.contains("sizeimage 1000"), "{e}");

    assert!(frame_interval_ok(25, 1, 25));
    assert!(frame_interval_ok(25, 1000, 25_000));
    assert!(!frame_interval_ok(25, 1, 30));
    assert!(!frame_interval_ok(25, 0, 0));
}

#[test]
fn sequence_counter_counts_gaps_and_wraps() {
    let mut c = SeqCounter::default();
    assert_eq!(c.step(7), (7, SeqStep::First));
    assert_eq!(c.step(8), (8, SeqStep::Next));
    assert_eq!(c.step(11), (11, SeqStep::Gap(2)));
    assert_eq!(c.step(11), (11, SeqStep::Backwards));
    assert_eq!(c.step(3), (11, SeqStep::Backwards));
    let mut c = SeqCounter::default();
    c.step(u32::MAX);
    assert_eq!(c.step(0), (1 << 32, SeqStep::Next));
    assert_eq!(c.step(1), ((1 << 32) + 1, SeqStep::Next));
}

#[test]
fn missing_devices_give_clear_errors() {
    let e = V4lCamera::open("/dev/video-does-not-exist", CaptureConfig::default()).err().unwrap();
    let msg = e.to_string();
    assert!(matches!(e, CaptureError::DeviceMissing { .. }), "{msg}");
    assert!(msg.contains("/dev/video-does-not-exist") && msg.contains("v4l2-ctl --list-devices"), "{msg}");

    let e = V4lCamera::open("/dev/null", CaptureConfig::default()).err().unwrap();
    let msg = e.to_string();
    assert!(matches!(e, CaptureError::NotVideoCapture { .. }), "{msg}");
    assert!(
        msg.contains("/dev/null") && msg.contains("not a V4L2") && msg.contains("v4l2-ctl --list-devices"),
        "{msg}"
    );

    let e = StereoCapture::open("/dev/null", "/dev/video-nope", CaptureConfig::default(), PairerConfig::default())
        .err()
        .unwrap();
    assert!(e.to_string().contains("/dev/null"), "{e}");
    let e = open_error(std::path::Path::new("/dev/video9"), std::io::Error::from(std::io::ErrorKind::NotFound));
    assert!(matches!(e, CaptureError::DeviceMissing { .. }));
}

// ---------------------------------------------------------------- capture threads on stand-ins

/// A camera stand-in: frames every 40 ms of simulated time, some dropped, some corrupt, then
/// poll timeouts (so the thread idles until the capture is dropped).
struct FakeCamera {
    next: usize,
    n: usize,
    drop_every: usize,
    corrupt_at: Option<usize>,
    fail_at: Option<usize>,
    jitter_ns: i64,
    seq_offset: u64,
    frame_sleep: Duration,
    /// Allocations made by the capture thread between consecutive calls (thread loop included).
    thread_allocs: Option<(std::sync::Arc<std::sync::atomic::AtomicU64>, Option<u64>)>,
}

impl FrameSource for FakeCamera {
    fn frame_len(&self) -> usize {
        16
    }

    fn next_frame(&mut self, mut gray: Vec<u8>) -> Result<Frame, CaptureError> {
        // Counted while frames flow (the idle timeouts after the last frame allocate their error).
        if let (Some((total, last)), true) = (&mut self.thread_allocs, self.next < self.n) {
            let now = allocs();
            if let Some(prev) = *last {
                total.fetch_add(now - prev, std::sync::atomic::Ordering::Relaxed);
            }
            *last = Some(now);
        }
        loop {
            let i = self.next;
            if i >= self.n {
                std::thread::sleep(Duration::from_millis(2));
                return Err(CaptureError::Timeout { path: "fake".into() });
            }
            self.next += 1;
            if self.fail_at == Some(i) {
                return Err(CaptureError::NotMonotonic { path: "fake".into(), clock: "of unknown clock", flags: 0 });
            }
            if self.corrupt_at == Some(i) {
                return Err(CaptureError::Corrupt { path: "fake".into(), seq: i as u32 });
            }
            if self.drop_every > 0 && i % self.drop_every == self.drop_every - 1 {
                continue;
            }
            gray.resize(16, i as u8);
            std::thread::sleep(self.frame_sleep);
            return Ok(Frame {
                seq: i as u64 + self.seq_offset,
                t_start_ns: 5_000_000_000 + i as i64 * PERIOD + self.jitter_ns,
                exposure_ns: 1_000_000,
                readout_anchor: 0.0,
                width: 4,
                height: 4,
                gray,
            });
        }
    }
}

fn fake(n: usize) -> FakeCamera {
    FakeCamera {
        next: 0,
        n,
        drop_every: 0,
        corrupt_at: None,
        fail_at: None,
        jitter_ns: 0,
        seq_offset: 0,
        frame_sleep: Duration::from_micros(200),
        thread_allocs: None,
    }
}

#[test]
fn stereo_capture_pairs_stand_in_cameras() {
    let left = FakeCamera { drop_every: 7, corrupt_at: Some(10), jitter_ns: 300_000, ..fake(60) };
    let right = FakeCamera { drop_every: 11, seq_offset: 1000, ..fake(60) };
    let mut cap = StereoCapture::from_sources(left, right, PairerConfig { window: 64, ..Default::default() });
    let mut pairs = Vec::new();
    loop {
        match cap.next_pair(Duration::from_millis(500)) {
            Ok(p) => {
                pairs.push((p.seq, p.left.seq, p.right.seq));
                cap.recycle(p);
            }
            Err(CaptureError::Timeout { .. }) => break,
            Err(e) => panic!("{e}"),
        }
    }
    let expected: Vec<u64> = (0..60u64).filter(|i| i % 7 != 6 && i % 11 != 10 && *i != 10).collect();
    assert_eq!(pairs.len(), expected.len());
    for (k, ((pseq, l, r), want)) in pairs.iter().zip(&expected).enumerate() {
        assert_eq!((*pseq, *l, *r), (k as u64, *want, want + 1000));
    }
    let s = cap.stats();
    assert_eq!(s.errors, [1, 0]);
    assert_eq!(s.pairing.input, [60 - 8 - 1, 60 - 5]);
    // Sequence gaps: left drops 8 frames + the corrupt one (never reached the pairer); right 5 (the last
    // drop, frame 54, is followed by 55).
    assert_eq!(s.pairing.dropped, [9, 5]);
}

#[test]
fn stereo_capture_stops_on_a_fatal_error() {
    let left = FakeCamera { fail_at: Some(3), ..fake(10) };
    let mut cap = StereoCapture::from_sources(left, fake(10), PairerConfig { window: 64, ..Default::default() });
    let mut n = 0;
    let err = loop {
        match cap.next_pair(Duration::from_secs(2)) {
            Ok(_) => n += 1,
            Err(e) => break e,
        }
    };
    assert!(matches!(err, CaptureError::NotMonotonic { .. }), "{err}");
    assert!(n <= 3);
    drop(cap); // joins both threads
}

#[test]
fn stereo_capture_recycles_buffers() {
    use std::sync::atomic::{AtomicU64, Ordering};
    use std::sync::Arc;
    let counts = [Arc::new(AtomicU64::new(0)), Arc::new(AtomicU64::new(0))];
    let n = 150;
    let cam = |c: &Arc<AtomicU64>| FakeCamera {
        frame_sleep: Duration::from_millis(1),
        thread_allocs: Some((c.clone(), None)),
        ..fake(n)
    };
    let mut cap = StereoCapture::from_sources(
        cam(&counts[0]),
        cam(&counts[1]),
        PairerConfig { window: 64, ..Default::default() },
    );
    let mut pairs = 0;
    while let Ok(p) = cap.next_pair(Duration::from_millis(500)) {
        pairs += 1;
        cap.recycle(p);
    }
    assert_eq!(pairs, n);
    let allocs = [counts[0].load(Ordering::Relaxed), counts[1].load(Ordering::Relaxed)];
    // Without recycling every frame would allocate its gray buffer (n per camera); with it only the
    // frames in flight before the first buffers come back do.
    assert!(allocs.iter().all(|&a| a < n as u64 / 3), "capture-thread allocations {allocs:?} for {n} frames");
}
