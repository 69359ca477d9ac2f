//! The serial drive board as the gaze controller sees it ([`BoardLink`]): command frames written by
//! `abvs_board::commands::CommandPort` on the port the encoder stream reads.
use abvs_board::commands::CommandPort;
use abvs_runtime_core::source::BoardLink;

/// A serial drive board: command frames written on a clone of the port the encoder stream reads (a newtype:
/// the contract lives in the bottom crate, the port in the board crate).
pub struct SerialBoard(pub CommandPort);

impl BoardLink for SerialBoard {
    fn home_counts(&self) -> Option<[[i64; 3]; 2]> {
        self.0.watch().home_counts()
    }

    fn last_record_ns(&self) -> Option<i64> {
        self.0.watch().last_record_ns()
    }

    fn send_move(&mut self, target_counts: [[i64; 3]; 2], duration_us: u32) -> Result<(), String> {
        self.0.send_move(target_counts, duration_us).map_err(|e| e.to_string())
    }
}
