//! The serial drive board ([`BoardLink`]): what the gaze controller sends the board, on the port the
//! encoder stream reads ([`crate::sources::encoder_link`]'s command frames).
use std::io::Write;

use abvs_runtime_core::source::BoardLink;

use crate::sources::encoder_link::{CommandFrame, COMMAND_MOVE};
use crate::sources::encoder_stream::EncoderWatch;

/// A serial drive board: command frames written on a clone of the port the encoder stream reads.
pub struct SerialBoard {
    writer: Box<dyn Write + Send>,
    watch: EncoderWatch,
    seq: u16,
    name: String,
}

impl SerialBoard {
    /// Commands on `writer` (the port `name`), homing and liveness from the encoder stream's `watch`.
    pub fn new(writer: Box<dyn Write + Send>, watch: EncoderWatch, name: String) -> SerialBoard {
        SerialBoard { writer, watch, seq: 0, name }
    }
}

impl BoardLink for SerialBoard {
    fn home_counts(&self) -> Option<[[i64; 3]; 2]> {
        self.watch.home_counts()
    }

    fn last_record_ns(&self) -> Option<i64> {
        self.watch.last_record_ns()
    }

    fn send_move(&mut self, target_counts: [[i64; 3]; 2], duration_us: u32) -> Result<(), String> {
        let home = self.home_counts().ok_or_else(|| format!("drive board {}: not homed", self.name))?;
        let mut bytes = [0u8; 2 * crate::sources::encoder_link::COMMAND_LEN];
        for e in 0..2 {
            let mut raw = [0i32; 3];
            for i in 0..3 {
                raw[i] = i32::try_from(home[e][i] + target_counts[e][i])
                    .map_err(|_| format!("drive board {}: target counts out of range", self.name))?;
            }
            let c = CommandFrame { seq: self.seq, eye: e as u8, kind: COMMAND_MOVE, target_counts: raw, duration_us };
            self.seq = self.seq.wrapping_add(1);
            let n = crate::sources::encoder_link::COMMAND_LEN;
            bytes[e * n..(e + 1) * n].copy_from_slice(&c.encode());
        }
        self.writer
            .write_all(&bytes)
            .and_then(|_| self.writer.flush())
            .map_err(|e| format!("drive board {}: {e}", self.name))
    }
}
