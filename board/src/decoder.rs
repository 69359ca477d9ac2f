//! Byte streams -> frames: the host's decoder of encoder frames and the board's decoder of commands. Both
//! resynchronise on their sync word after garbage and count what they dropped.
use std::collections::VecDeque;

use crate::protocol::{
    BoardFrame, CommandFrame, COMMAND_LEN, COMMAND_MOVE, COMMAND_SYNC, COMMAND_VERSION, CRC16, FRAME_LEN, SYNC, VERSION,
};

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::CRC16;

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
