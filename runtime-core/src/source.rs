//! The source contracts: where the graph's stereo pairs come from ([`PairSource`]), the encoder samples on
//! the same clock ([`EncoderFeed`], handed to whoever aligns frames to them through a callback) and the
//! command side of the drive board ([`BoardLink`]). The runtime's sources implement them (a recorded
//! session, the live cameras and board); a toolkit hands its own (the simulated head).
use crate::messages::{EncoderSample, SourcePair};
use crate::stats::RunStats;

/// Where the graph's stereo pairs come from: a recorded session or the live cameras (the runtime's
/// `sources::replay::ReplaySource`, `sources::live::LiveSource`), or a source of one's own.
pub trait PairSource: Send {
    /// Raw frame size (both eyes).
    fn size(&self) -> (u32, u32);
    /// Anchors the source's clock to `now_ns` (CLOCK_MONOTONIC) and hands out its encoder stream,
    /// which the time-alignment stage reads on another thread.
    fn start(&mut self, now_ns: i64) -> Box<dyn EncoderFeed>;
    /// The next pair, or `None` when the source is done (`limit` pairs, end of a replay, capture stopped).
    fn next_frame(&mut self, limit: Option<u64>) -> Option<SourcePair<'_>>;
    /// Adds what the source counted (unreadable files, capture drops) to the run's statistics.
    fn finish(&mut self, _stats: &mut RunStats) {}
    /// Hands out the command side of the drive board (once, at the start; `None`: no board, a replay).
    fn board(&mut self) -> Option<Box<dyn BoardLink>> {
        None
    }
}

/// The encoder samples of a [`PairSource`], on its clock.
pub trait EncoderFeed: Send {
    /// Hands every sample stamped up to `t_ns` to `push`, with its eye (0 left, 1 right), oldest first per
    /// eye (a live feed waits briefly for samples still on the wire). What the receiver refuses is its own
    /// to count.
    fn feed(&mut self, t_ns: i64, push: &mut dyn FnMut(usize, EncoderSample));
}

/// A source chosen at run time (e.g. the toolkit's simulated head, handed to the runtime's
/// `Runtime::with_source`).
impl PairSource for Box<dyn PairSource> {
    fn size(&self) -> (u32, u32) {
        (**self).size()
    }
    fn start(&mut self, now_ns: i64) -> Box<dyn EncoderFeed> {
        (**self).start(now_ns)
    }
    fn next_frame(&mut self, limit: Option<u64>) -> Option<SourcePair<'_>> {
        (**self).next_frame(limit)
    }
    fn finish(&mut self, stats: &mut RunStats) {
        (**self).finish(stats)
    }
    fn board(&mut self) -> Option<Box<dyn BoardLink>> {
        (**self).board()
    }
}

/// The drive board as the gaze controller sees it: the command side of the port the encoder stream reads.
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
