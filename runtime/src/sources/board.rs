//! The command side of the drive board link as the gaze controller sees it ([`BoardLink`]): a serial board
//! (`abvs_board::commands::CommandPort`, on the port the encoder stream reads) or a simulated head.
use abvs_board::commands::CommandPort;

/// The drive board as the gaze controller sees it.
pub trait BoardLink: Send {
    /// Both eyes' home counts (raw), once both are homed.
    fn home_counts(&self) -> Option<[[i64; 3]; 2]>;
    /// CLOCK_MONOTONIC ns at which the newest homed encoder record arrived (`None` before any).
    fn last_record_ns(&self) -> Option<i64>;
    /// Both eyes move to `target_counts` (homed) over `duration_us` (minimum jerk): one command frame per eye.
    fn send_move(&mut self, target_counts: [[i64; 3]; 2], duration_us: u32) -> Result<(), String>;
    /// A simulated board's virtual clock: the instant (ns, the frames' clock) at which the controller acts on a
    /// frame whose last row's exposure ended at `exposure_end_ns`. `None` (a real board): CLOCK_MONOTONIC now.
    fn virtual_now_ns(&self, _exposure_end_ns: i64) -> Option<i64> {
        None
    }
    /// The gaze stage is done with frame `seq` (its commands, if any, were sent): a simulated head renders
    /// the next frame only then (lockstep). A real board ignores it.
    fn frame_done(&mut self, _seq: u64) {}
}

/// A serial drive board: command frames written on a clone of the port the encoder stream reads.
impl BoardLink for CommandPort {
    fn home_counts(&self) -> Option<[[i64; 3]; 2]> {
        self.watch().home_counts()
    }

    fn last_record_ns(&self) -> Option<i64> {
        self.watch().last_record_ns()
    }

    fn send_move(&mut self, target_counts: [[i64; 3]; 2], duration_us: u32) -> Result<(), String> {
        CommandPort::send_move(self, target_counts, duration_us).map_err(|e| e.to_string())
    }
}
