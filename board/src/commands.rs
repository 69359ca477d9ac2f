//! Host -> board: yoked moves of both eyes as command frames, on the port the encoder stream reads.
use std::io::Write;

use crate::error::BoardError;
use crate::protocol::{CommandFrame, COMMAND_LEN, COMMAND_MOVE};
use crate::watch::EncoderWatch;

/// Both eyes' command frames of one move to `target_counts` (homed, per eye) over `duration_us`: raw targets
/// are the home counts plus the homed ones. `seq` numbers the commands (+1 each).
pub fn move_commands(
    seq: &mut u16,
    home: [[i64; 3]; 2],
    target_counts: [[i64; 3]; 2],
    duration_us: u32,
    port: &str,
) -> Result<[u8; 2 * COMMAND_LEN], BoardError> {
    let mut bytes = [0u8; 2 * COMMAND_LEN];
    for e in 0..2 {
        let mut raw = [0i32; 3];
        for i in 0..3 {
            raw[i] = i32::try_from(home[e][i] + target_counts[e][i])
                .map_err(|_| BoardError::TargetOutOfRange { port: port.to_string() })?;
        }
        let c = CommandFrame { seq: *seq, eye: e as u8, kind: COMMAND_MOVE, target_counts: raw, duration_us };
        *seq = seq.wrapping_add(1);
        bytes[e * COMMAND_LEN..(e + 1) * COMMAND_LEN].copy_from_slice(&c.encode());
    }
    Ok(bytes)
}

/// The command side of a board port: moves written on a clone of the port the encoder stream reads, with
/// the homing that stream found ([`crate::stream::EncoderStream::take_commands`]).
pub struct CommandPort {
    writer: Box<dyn Write + Send>,
    watch: EncoderWatch,
    seq: u16,
    name: String,
}

impl CommandPort {
    /// Commands on `writer` (the port `name`), homing and liveness from the encoder stream's `watch`.
    pub fn new(writer: Box<dyn Write + Send>, watch: EncoderWatch, name: String) -> CommandPort {
        CommandPort { writer, watch, seq: 0, name }
    }

    /// Homing and liveness of the encoder stream on the same port.
    pub fn watch(&self) -> &EncoderWatch {
        &self.watch
    }

    /// Both eyes move to `target_counts` (homed) over `duration_us` (minimum jerk): one command frame per eye.
    pub fn send_move(&mut self, target_counts: [[i64; 3]; 2], duration_us: u32) -> Result<(), BoardError> {
        let home = self.watch.home_counts().ok_or_else(|| BoardError::NotHomed { port: self.name.clone() })?;
        let bytes = move_commands(&mut self.seq, home, target_counts, duration_us, &self.name)?;
        self.writer
            .write_all(&bytes)
            .and_then(|_| self.writer.flush())
            .map_err(|source| BoardError::Write { port: self.name.clone(), source })
    }
}
