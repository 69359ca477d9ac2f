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
//!
//! ## Command frame (host -> board, little endian, 25 bytes; [`CommandFrame`])
//! | bytes | field |
//! | --- | --- |
//! | 0-1 | sync `A5 5C` |
//! | 2 | command protocol version ([`COMMAND_VERSION`] = 1; a board ignores and counts others) |
//! | 3-4 | sequence number (u16, +1 per command) |
//! | 5 | eye (0 left, 1 right) |
//! | 6 | kind (1: move) |
//! | 7-18 | target raw counts of links 1..3 (i32 each, the encoder frames' count origin) |
//! | 19-22 | duration (u32, microseconds) |
//! | 23-24 | CRC-16/CCITT-FALSE over bytes 2..=22 |
//!
//! A move starts when the board receives it, from wherever the links are (a move under way is
//! replaced), and follows the minimum-jerk profile of `abvs_eye::saccade` in link space to the
//! target counts over the duration; the encoder frames report the motion as it happens. The host
//! converts homed targets to raw counts with the home counts its homing found.
//!
//! Both directions share one port: the live runtime reads the encoder frames and writes the gaze
//! controller's command frames on it (`sources::board::SerialBoard`, a clone of the port the encoder
//! stream reads; one move command per eye per goal, and per frame while pursuing). The protocol is
//! unchanged by that (encoder frames v1, command frames v1); a change of either frame's layout or
//! meaning takes a new version byte.
use crc::{Crc, CRC_16_IBM_3740};
use std::collections::VecDeque;

/// First two bytes of every encoder frame.
pub const SYNC: [u8; 2] = [0xA5, 0x5A];
/// Protocol version of the encoder frames.
pub const VERSION: u8 = 1;
/// Bytes in one encoder frame (sync, version, seq, time, eye, counts, index, CRC-16).
pub const FRAME_LEN: usize = 29;
const CRC16: Crc<u16> = Crc::<u16>::new(&CRC_16_IBM_3740);

/// One encoder frame from the drive board.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BoardFrame {
    /// Frame sequence number (wraps at 2^16; gaps are lost frames).
    pub seq: u16,
    /// The board's clock when the counts were latched (us since its start).
    pub board_time_us: u64,
    /// Which eye: 0 left, 1 right.
    pub eye: u8,
    /// Raw counts of links 1..3 (the board's origin; homing maps them to angles).
    pub counts: [i32; 3],
    /// Bits of the index markers seen (homing).
    pub index: u8,
}

impl BoardFrame {
    /// The frame's bytes on the wire, CRC included.
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

/// First two bytes of every command frame.
pub const COMMAND_SYNC: [u8; 2] = [0xA5, 0x5C];
/// Protocol version of the command frames.
pub const COMMAND_VERSION: u8 = 1;
/// Bytes in one command frame (sync, version, seq, eye, kind, targets, duration, CRC-16).
pub const COMMAND_LEN: usize = 25;
/// Command kind: move to target counts over a duration (minimum jerk).
pub const COMMAND_MOVE: u8 = 1;

/// A command to the drive board (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CommandFrame {
    /// Command sequence number.
    pub seq: u16,
    /// Which eye: 0 left, 1 right.
    pub eye: u8,
    /// What to do: [`COMMAND_MOVE`].
    pub kind: u8,
    /// Raw counts (the encoder frames' origin) of links 1..3 at the end of the move.
    pub target_counts: [i32; 3],
    /// Duration of the move (us).
    pub duration_us: u32,
}

impl CommandFrame {
    /// The command's bytes on the wire, CRC included.
    pub fn encode(&self) -> [u8; COMMAND_LEN] {
        let mut b = [0u8; COMMAND_LEN];
        b[0..2].copy_from_slice(&COMMAND_SYNC);
        b[2] = COMMAND_VERSION;
        b[3..5].copy_from_slice(&self.seq.to_le_bytes());
        b[5] = self.eye;
        b[6] = self.kind;
        for i in 0..3 {
            b[7 + 4 * i..11 + 4 * i].copy_from_slice(&self.target_counts[i].to_le_bytes());
        }
        b[19..23].copy_from_slice(&self.duration_us.to_le_bytes());
        let crc = CRC16.checksum(&b[2..23]);
        b[23..25].copy_from_slice(&crc.to_le_bytes());
        b
    }
}

/// What a board's command decoder saw.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct CommandStats {
    /// Commands decoded.
    pub commands: u64,
    /// Frames whose CRC did not match (dropped).
    pub crc_errors: u64,
    /// Commands of another protocol version or an unknown kind (ignored).
    pub unsupported: u64,
    /// Bytes skipped while looking for a sync word.
    pub skipped_bytes: u64,
}

/// Byte stream -> commands (the board's side), resynchronising like [`Decoder`].
#[derive(Debug, Default)]
pub struct CommandDecoder {
    buf: VecDeque<u8>,
    /// What was seen so far.
    pub stats: CommandStats,
}

impl CommandDecoder {
    /// A decoder with nothing buffered.
    pub fn new() -> Self {
        Self::default()
    }

    /// Appends bytes and returns every command complete in them (partial ones wait for more bytes).
    pub fn feed(&mut self, bytes: &[u8]) -> Vec<CommandFrame> {
        self.buf.extend(bytes);
        let mut out = vec![];
        loop {
            while self.buf.len() >= 2 && (self.buf[0], self.buf[1]) != (COMMAND_SYNC[0], COMMAND_SYNC[1]) {
                self.buf.pop_front();
                self.stats.skipped_bytes += 1;
            }
            if self.buf.len() < COMMAND_LEN {
                break;
            }
            let b: Vec<u8> = self.buf.iter().take(COMMAND_LEN).copied().collect();
            if CRC16.checksum(&b[2..23]) != u16::from_le_bytes([b[23], b[24]]) {
                self.stats.crc_errors += 1;
                self.buf.pop_front();
                self.stats.skipped_bytes += 1;
                continue;
            }
            self.buf.drain(..COMMAND_LEN);
            if b[2] != COMMAND_VERSION || b[6] != COMMAND_MOVE {
                self.stats.unsupported += 1;
                continue;
            }
            let i32_at = |k: usize| i32::from_le_bytes(b[k..k + 4].try_into().expect("4 bytes"));
            self.stats.commands += 1;
            out.push(CommandFrame {
                seq: u16::from_le_bytes([b[3], b[4]]),
                eye: b[5],
                kind: b[6],
                target_counts: [i32_at(7), i32_at(11), i32_at(15)],
                duration_us: u32::from_le_bytes(b[19..23].try_into().expect("4 bytes")),
            });
        }
        out
    }
}

/// What the decoder saw, for the runtime's statistics.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct LinkStats {
    /// Frames decoded.
    pub frames: u64,
    /// Frames whose CRC did not match (dropped).
    pub crc_errors: u64,
    /// Frames of another protocol version (dropped).
    pub bad_version: u64,
    /// Bytes skipped while looking for a sync word.
    pub skipped_bytes: u64,
    /// Frames missing according to the sequence numbers.
    pub lost_frames: u64,
    /// Board restarts seen (its clock went back).
    pub resets: u64,
}

/// What the decoder makes of a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkEvent {
    /// A frame of the running session.
    Frame(BoardFrame),
    /// The board restarted: this frame starts a new session (re-home, re-map the clock).
    Reset(BoardFrame),
}

/// Byte stream -> frames.
#[derive(Debug, Default)]
pub struct Decoder {
    buf: VecDeque<u8>,
    last: Option<(u16, u64)>,
    /// What was seen so far.
    pub stats: LinkStats,
}

impl Decoder {
    /// A decoder with nothing buffered.
    pub fn new() -> Self {
        Self::default()
    }

    /// Appends bytes and returns every frame complete in them (partial ones wait for more bytes).
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
    /// A map fitting over the last `capacity` frames (at least 16).
    pub fn new(capacity: usize) -> Self {
        ClockMap { obs: VecDeque::with_capacity(capacity), capacity: capacity.max(16), fit: None }
    }

    /// Forgets every observation (after a board reset).
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn command_frames_round_trip_through_garbage_and_errors() {
        let c = CommandFrame {
            seq: 7,
            eye: 1,
            kind: COMMAND_MOVE,
            target_counts: [-123_456, 7, 2_000_000_000],
            duration_us: 36_028,
        };
        let mut bytes = vec![0x00, 0xA5, 0x13];
        bytes.extend(c.encode());
        let mut bad = c.encode();
        bad[10] ^= 0x01; // corrupt
        bytes.extend(bad);
        let mut other = CommandFrame { seq: 8, ..c }.encode();
        other[2] = 2; // a future version: CRC recomputed, still ignored
        let crc = CRC16.checksum(&other[2..23]);
        other[23..25].copy_from_slice(&crc.to_le_bytes());
        bytes.extend(other);
        // An encoder frame on the same wire is skipped as garbage.
        bytes.extend(BoardFrame { seq: 1, board_time_us: 5, eye: 0, counts: [1, 2, 3], index: 0 }.encode());
        bytes.extend(CommandFrame { seq: 9, ..c }.encode());
        let mut d = CommandDecoder::new();
        // Fed in small pieces, as a port delivers them.
        let got: Vec<CommandFrame> = bytes.chunks(5).flat_map(|b| d.feed(b)).collect();
        assert_eq!(got, vec![c, CommandFrame { seq: 9, ..c }]);
        assert_eq!((d.stats.commands, d.stats.crc_errors, d.stats.unsupported), (2, 1, 1));
    }
}
