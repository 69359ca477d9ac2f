//! The encoder protocol: framing round trip, resync after garbage, clock mapping under jitter.
use abvs_board::clock::ClockMap;
use abvs_board::decoder::{Decoder, LinkEvent};
use abvs_board::protocol::{BoardFrame, FRAME_LEN};
use abvs_sim::board::BoardSim;

#[test]
fn frames_round_trip_and_garbage_is_skipped_and_counted() {
    let f = BoardFrame { seq: 65535, board_time_us: 1 << 40, eye: 1, counts: [-5, i32::MAX, 7], index: 0b101 };
    let mut d = Decoder::new();
    let mut bytes = vec![0x00, 0xA5, 0x13, 0x5A];
    bytes.extend(f.encode());
    let g = BoardFrame { seq: 1, board_time_us: (1 << 40) + 1000, ..f };
    bytes.extend(g.encode());
    // Fed in awkward pieces, as a serial read returns them.
    let mut events = vec![];
    for chunk in bytes.chunks(5) {
        events.extend(d.feed(chunk));
    }
    assert_eq!(events, vec![LinkEvent::Frame(f), LinkEvent::Frame(g)]);
    assert_eq!(d.stats.skipped_bytes, 4);
    // seq 65535 -> 1 wraps and loses frame 0.
    assert_eq!(d.stats.lost_frames, 1);
    assert_eq!(d.stats.frames, 2);
    assert_eq!(f.encode().len(), FRAME_LEN);
}

#[test]
fn corrupted_dropped_and_reset_frames_are_counted_never_fatal() {
    let sim = BoardSim { frames: 1000, rate_hz: 1000.0, corrupt_every: 37, drop_every: 53, reset_after: Some(700) };
    let mut d = Decoder::new();
    let mut got = vec![];
    for f in sim.frames() {
        got.extend(d.feed(&f));
    }
    let dropped = (0..1000).filter(|k| k % 53 == 52).count() as u64;
    let corrupted = (0..1000).filter(|k| k % 37 == 36 && k % 53 != 52).count() as u64;
    assert_eq!(d.stats.frames, 1000 - dropped - corrupted);
    assert!(d.stats.crc_errors >= corrupted);
    assert_eq!(d.stats.lost_frames, dropped + corrupted);
    assert_eq!(d.stats.resets, 1);
    assert_eq!(got.iter().filter(|e| matches!(e, LinkEvent::Reset(_))).count(), 1);
}

#[test]
fn clock_map_recovers_board_time_under_latency_jitter() {
    // Board clock 12.3 s behind CLOCK_MONOTONIC and 50 ppm fast; USB latency 0.2 ms + jitter.
    let (offset, drift) = (12.3, -50e-6);
    let mut map = ClockMap::new(4000);
    let mut state = 0x2545F4914F6CDD1Du64;
    let mut rand01 = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut worst: f64 = 0.0;
    for k in 0..5000u64 {
        let board_us = 1000 + k * 1000;
        let b = board_us as f64 * 1e-6;
        let event_host = b + offset + drift * b;
        let latency = 0.0002 - 0.0005 * (1.0 - rand01()).ln();
        map.observe(board_us, event_host + latency);
        if k > 1000 {
            // The constant part of the latency is indistinguishable from the clock offset (no
            // round trip on this link): it ends up in the eye's encoder_time_offset. What the map
            // must remove is the drift and the jitter.
            worst = worst.max((map.to_host(board_us).unwrap() - (event_host + 0.0002)).abs());
        }
    }
    assert!(worst < 5e-5, "worst mapping error {:.1} us", worst * 1e6);
}

/// The live tracker on a simulated board replaying the fixture's encoders: homing finds the
/// board's origins exactly, the homed counts are the fixture's, and after a board reset (the
/// board replays from power-on, sequence and clock from zero) both eyes home again.
#[test]
fn tracker_homes_maps_and_rehomes_after_a_board_reset() {
    use abvs_board::tracker::EncoderTracker;
    use abvs_runtime_core::session::Session;
    use abvs_sim::board::SessionBoard;
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/session");
    let session = Session::open(&dir).unwrap();
    let board = SessionBoard { corrupt_every: 301, ..SessionBoard::from_seed(3) };
    let script = board.script(&session.encoders).unwrap();
    let mut tracker = EncoderTracker::new();
    let mut out = vec![];
    // Host clock = session clock + 5 s, 80 us of transport latency.
    let shift = 5_000_000_000i64;
    for (t, bytes) in &script {
        tracker.feed(bytes, t + shift + 80_000, &mut out);
    }
    let s = tracker.stats();
    assert_eq!(s.home_counts, [Some(board.origin[0]), Some(board.origin[1])]);
    assert!(s.link.crc_errors > 0 && s.link.lost_frames > 0 && s.homing_failures == [0, 0], "{s:?}");
    let first = session.encoders[0].t_ns + shift;
    let in_session: Vec<_> = out.iter().filter(|r| r.t_ns >= first - 500_000).copied().collect();
    let expected = session.encoders.len() as u64;
    assert!(in_session.len() as u64 + s.link.lost_frames >= expected && in_session.len() as u64 <= expected);
    // Every emitted sample is the fixture's, at its time + the constant latency (which the clock
    // map cannot tell from the offset: it belongs to the eye's encoder_time_offset).
    // Board time is sent in whole microseconds: within 2 us.
    for r in &in_session {
        let t = r.t_ns - shift - 80_000;
        let f = session.encoders.iter().filter(|f| f.eye == r.eye).min_by_key(|f| (f.t_ns - t).abs()).unwrap();
        assert!((f.t_ns - t).abs() < 2_000, "eye {} at {t}: nearest fixture sample {}", r.eye, f.t_ns);
        assert_eq!([f.count1, f.count2, f.count3], r.counts);
    }

    // A frame from an eye that does not exist is counted, not used.
    let bogus =
        abvs_board::protocol::BoardFrame { seq: 0, board_time_us: u64::MAX / 2, eye: 5, counts: [0; 3], index: 0 };
    tracker.feed(&bogus.encode(), 0, &mut out);
    assert_eq!(tracker.stats().bad_eye, 1);

    // The board resets and replays from power-on: both eyes home again from their new roll.
    let n_before = out.len();
    for (t, bytes) in &script {
        tracker.feed(bytes, t + 2 * shift + 80_000, &mut out);
    }
    let s = tracker.stats();
    assert_eq!(s.link.resets, 1, "{s:?}");
    assert_eq!(s.home_counts, [Some(board.origin[0]), Some(board.origin[1])]);
    assert!(out.len() - n_before >= in_session.len() - 5, "{} after the reset", out.len() - n_before);
}
