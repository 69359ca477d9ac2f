//! Sources: where data enters the runtime (cameras, the encoder board, recorded sessions).
pub mod board;
pub mod devices;
pub mod live;
pub mod pairing;
pub mod pixel;
pub mod replay;
pub mod v4l_capture;

pub use crate::messages::{Frame, FramePair, SourcePair};
use crate::stats::RunStats;
use crate::tasks::align::EncoderTrack;

/// Where the graph's stereo pairs come from: a recorded session ([`replay::ReplaySource`]) or the live
/// cameras ([`live::LiveSource`]).
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
    fn board(&mut self) -> Option<Box<dyn board::BoardLink>> {
        None
    }
}

/// The encoder samples of a [`PairSource`], on its clock.
pub trait EncoderFeed: Send {
    /// Pushes every sample stamped up to `t_ns` into the eyes' tracks (a live feed waits briefly
    /// for samples still on the wire).
    fn feed(&mut self, t_ns: i64, tracks: &mut [EncoderTrack; 2]);
}

/// A source chosen at run time (e.g. the toolkit's simulated head, [`crate::Runtime::with_source`]).
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
    fn board(&mut self) -> Option<Box<dyn board::BoardLink>> {
        (**self).board()
    }
}
