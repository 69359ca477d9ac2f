//! The drive board's wire protocol: encoder frames (board -> host) and command frames (host -> board).
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
//! The decoders ([`crate::decoder`]) resynchronise on the sync word after garbage, count CRC failures,
//! sequence gaps (frames lost on the wire) and board resets (sequence and board time jump back), and never
//! stop: a long run survives a bad byte and says how many it saw.
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
//! controller's command frames on it ([`crate::commands::CommandPort`], a clone of the port the encoder
//! stream reads; one move command per eye per goal, and per frame while pursuing). The protocol is
//! unchanged by that (encoder frames v1, command frames v1); a change of either frame's layout or
//! meaning takes a new version byte.
use crc::{Crc, CRC_16_IBM_3740};

/// First two bytes of every encoder frame.
pub const SYNC: [u8; 2] = [0xA5, 0x5A];
/// Protocol version of the encoder frames.
pub const VERSION: u8 = 1;
/// Bytes in one encoder frame (sync, version, seq, time, eye, counts, index, CRC-16).
pub const FRAME_LEN: usize = 29;
pub(crate) const CRC16: Crc<u16> = Crc::<u16>::new(&CRC_16_IBM_3740);

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

    pub(crate) fn decode(b: &[u8]) -> BoardFrame {
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
