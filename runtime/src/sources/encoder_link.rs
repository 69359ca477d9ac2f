//! The drive board's encoder stream over a serial port: framing, integrity, clock mapping.
//!
//! ## Frame (little endian, 29 bytes)
//! | bytes | field |
//! | --- | --- |
//! | 0-1 | sync `A5 5A` |
//! | 2 | protocol version (1) |
//! | 3-4 | sequence number (u16, +1 per frame, wraps) |
//! | 5-12 | board time (u64, microseconds since board start) |
//! | 13 | eye (0 left, 1 right) |
//! | 14-25 | counts of links 1..3 (i32 each, raw incremental) |
//! | 26 | index flags (bit i: link i+1's head is on a marker) |
//! | 27-28 | CRC-16/CCITT-FALSE over bytes 2..=26 |
//!
//! The decoder resynchronises on the sync word after garbage, counts CRC failures, sequence gaps
//! (frames lost on the wire) and board resets (sequence and board time jump back), and never
//! stops: a long run survives a bad byte and says how many it saw.
use crc::{Crc, CRC_16_IBM_3740};
use std::collections::VecDeque;

pub const SYNC: [u8; 2] = [0xA5, 0x5A];
pub const VERSION: u8 = 1;
pub const FRAME_LEN: usize = 29;
const CRC16: Crc<u16> = Crc::<u16>::new(&CRC_16_IBM_3740);

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BoardFrame {
    pub seq: u16,
    pub board_time_us: u64,
    pub eye: u8,
    pub counts: [i32; 3],
    pub index: u8,
}

impl BoardFrame {
    pub fn encode(&self) -> [u8; FRAME_LEN] {
        let mut b = [0u8; FRAME_LEN];
        b[0..2].copy_from_slice(&SYNC);
        b[2] = VERSION;
        b[3..5].copy_from_slice(&self.seq.to_le_bytes());
        b[5..13].copy_from_slice(&self.board_time_us.to_le_bytes());
        b[13] = self.eye;
        for i in 0..3 {
            b[14 + 4 * i..18 + 4 * i].copy_from_slice(&self.counts[i].to_le_bytes());
        }
        b[26] = self.index;
        let crc = CRC16.checksum(&b[2..27]);
        b[27..29].copy_from_slice(&crc.to_le_bytes());
        b
    }

    fn decode(b: &[u8]) -> BoardFrame {
        let i32_at = |k: usize| i32::from_le_bytes(b[k..k + 4].try_into().expect("4 bytes"));
        BoardFrame {
            seq: u16::from_le_bytes([b[3], b[4]]),
            board_time_us: u64::from_le_bytes(b[5..13].try_into().expect("8 bytes")),
            eye: b[13],
            counts: [i32_at(14), i32_at(18), i32_at(22)],
            index: b[26],
        }
    }
}

/// What the decoder saw, for the runtime's statistics.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct LinkStats {
    pub frames: u64,
    pub crc_errors: u64,
    pub bad_version: u64,
    /// Bytes skipped while looking for a sync word.
    pub skipped_bytes: u64,
    /// Frames missing according to the sequence numbers.
    pub lost_frames: u64,
    pub resets: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkEvent {
    Frame(BoardFrame),
    /// The board restarted: this frame starts a new session (re-home, re-map the clock).
    Reset(BoardFrame),
}

/// Byte stream -> frames.
#[derive(Debug, Default)]
pub struct Decoder {
    buf: VecDeque<u8>,
    last: Option<(u16, u64)>,
    pub stats: LinkStats,
}

impl Decoder {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn feed(&mut self, bytes: &[u8]) -> Vec<LinkEvent> {
        self.buf.extend(bytes);
        let mut out = vec![];
        loop {
            // Find the sync word.
            while self.buf.len() >= 2 && (self.buf[0], self.buf[1]) != (SYNC[0], SYNC[1]) {
                self.buf.pop_front();
                self.stats.skipped_bytes += 1;
            }
            if self.buf.len() < FRAME_LEN {
                break;
            }
            let frame: Vec<u8> = self.buf.iter().take(FRAME_LEN).copied().collect();
            let crc = u16::from_le_bytes([frame[27], frame[28]]);
            if CRC16.checksum(&frame[2..27]) != crc {
                // Corrupt, or a false sync inside data: drop one byte and search again.
                self.stats.crc_errors += 1;
                self.buf.pop_front();
                self.stats.skipped_bytes += 1;
                continue;
            }
            self.buf.drain(..FRAME_LEN);
            if frame[2] != VERSION {
                self.stats.bad_version += 1;
                continue;
            }
            let f = BoardFrame::decode(&frame);
            self.stats.frames += 1;
            let event = match self.last {
                Some((seq, t)) if f.board_time_us < t => {
                    let _ = seq;
                    self.stats.resets += 1;
                    LinkEvent::Reset(f)
                }
                Some((seq, _)) => {
                    self.stats.lost_frames += u64::from(f.seq.wrapping_sub(seq).wrapping_sub(1));
                    LinkEvent::Frame(f)
                }
                None => LinkEvent::Frame(f),
            };
            self.last = Some((f.seq, f.board_time_us));
            out.push(event);
        }
        out
    }
}

/// Maps board time to CLOCK_MONOTONIC. Each frame gives `host_rx - board = offset + drift *
/// board + latency`, latency >= 0 and jittery; the lower envelope of that difference is the
/// clock relation. Drift is fitted over the window's per-block minima, the offset is the
/// window's minimum after removing the drift. The constant part of the transport latency cannot
/// be told from the offset on a one-way link; it is calibrated as the eye's encoder_time_offset.
#[derive(Debug, Clone)]
pub struct ClockMap {
    obs: VecDeque<(f64, f64)>,
    capacity: usize,
    fit: Option<(f64, f64)>,
}

impl ClockMap {
    pub fn new(capacity: usize) -> Self {
        ClockMap { obs: VecDeque::with_capacity(capacity), capacity: capacity.max(16), fit: None }
    }

    pub fn reset(&mut self) {
        self.obs.clear();
        self.fit = None;
    }

    /// Records a frame's board time (us) and its host receive time (s, CLOCK_MONOTONIC).
    pub fn observe(&mut self, board_us: u64, host_s: f64) {
        if self.obs.len() == self.capacity {
            self.obs.pop_front();
        }
        let b = board_us as f64 * 1e-6;
        self.obs.push_back((b, host_s - b));
        self.refit();
    }

    fn refit(&mut self) {
        let n = self.obs.len();
        if n < 8 {
            self.fit = self.obs.iter().map(|o| o.1).reduce(f64::min).map(|m| (m, 0.0));
            return;
        }
        // Minima of 8 blocks carry the envelope; a line through them gives the drift.
        let block = n / 8;
        let mins: Vec<(f64, f64)> = (0..8)
            .map(|k| {
                self.obs.iter().skip(k * block).take(block).copied().fold((0.0, f64::MAX), |m, o| {
                    if o.1 < m.1 {
                        o
                    } else {
                        m
                    }
                })
            })
            .collect();
        let (mx, my) = mins.iter().fold((0.0, 0.0), |a, m| (a.0 + m.0 / 8.0, a.1 + m.1 / 8.0));
        let sxx: f64 = mins.iter().map(|m| (m.0 - mx).powi(2)).sum();
        let sxy: f64 = mins.iter().map(|m| (m.0 - mx) * (m.1 - my)).sum();
        let drift = if sxx > 0.0 { sxy / sxx } else { 0.0 };
        let offset = self.obs.iter().map(|o| o.1 - drift * o.0).fold(f64::MAX, f64::min);
        self.fit = Some((offset, drift));
    }

    /// CLOCK_MONOTONIC time (s) of a board time (us), once anything was observed.
    pub fn to_host(&self, board_us: u64) -> Option<f64> {
        let (offset, drift) = self.fit?;
        let b = board_us as f64 * 1e-6;
        Some(b + offset + drift * b)
    }
}

/// Opens a serial port (a real one, or a pseudo-terminal) for the encoder stream.
pub fn open_port(path: &str, baud: u32) -> Result<Box<dyn serialport::SerialPort>, String> {
    serialport::new(path, baud)
        .timeout(std::time::Duration::from_millis(200))
        .open()
        .map_err(|e| format!("encoder port {path}: {e}"))
}
