//! Replay source: a recorded session played back as if live.
//!
//! Frames are decoded once at start-up (sessions are short; decoding per frame would allocate and cost more
//! than the pipeline), then copied into the pipeline's pooled buffers. Timestamps are shifted onto this
//! process's CLOCK_MONOTONIC so latency means the same as live; when more frames are asked for than the
//! session holds it loops, with timestamps (frames and encoders) kept increasing.
//!
//! Every row of frames.csv keeps its identity: its `seq` (ground truth is looked up by it) and its time (the
//! encoders are). A frame whose file is missing, unreadable or of the wrong size is reported by path at
//! start-up and counted in `frames_failed` with its reason each time the replay reaches it; it shifts nothing.
use std::path::PathBuf;

use crate::error::{Result, RuntimeError};
use crate::session::{EncoderRecord, Session};
use crate::tasks::align::{EncoderSample, EncoderTrack};

/// A decoded stereo frame of the session.
struct Decoded {
    left: Vec<u8>,
    right: Vec<u8>,
}

/// Why a frame of the session cannot be replayed (the `frames_failed` reasons of the replay).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameFault {
    // (the discriminants index the replay's counters, in the order of `ALL`)
    /// A frame file named by frames.csv does not exist.
    Missing,
    /// A frame file exists but does not decode as an image.
    Unreadable,
    /// A frame file decodes to another size than session.toml says.
    WrongSize,
}

impl FrameFault {
    pub const ALL: [FrameFault; 3] = [FrameFault::Missing, FrameFault::Unreadable, FrameFault::WrongSize];

    /// The reason as counted in `frames_failed`.
    pub fn reason(self) -> &'static str {
        match self {
            FrameFault::Missing => "frame file missing",
            FrameFault::Unreadable => "frame file unreadable",
            FrameFault::WrongSize => "frame file of the wrong size",
        }
    }
}

/// One row of frames.csv: its identity and time, and its images or why there are none.
struct Slot {
    seq: u64,
    t_start_ns: i64,
    exposure_ns: i64,
    frame: std::result::Result<Decoded, FrameFault>,
}

/// What the replay hands the pipeline for one pair (written into pooled buffers).
pub struct ReplayFrame<'a> {
    /// The frame's `seq` in its session (before looping; for a live camera its frame number): the key of
    /// its ground truth.
    pub session_seq: u64,
    /// Pipeline sequence number (keeps increasing when a replay loops).
    pub seq: u64,
    pub t_start_ns: i64,
    /// The right frame's start of exposure (live pairs differ by up to the pairing tolerance).
    pub right_t_start_ns: i64,
    pub exposure_ns: i64,
    pub left: &'a [u8],
    pub right: &'a [u8],
}

pub struct ReplaySource {
    pub session: Session,
    /// One slot per row of frames.csv, in order.
    slots: Vec<Slot>,
    /// Files that could not be used: (path, reason).
    pub bad_frames: Vec<(PathBuf, String)>,
    /// Frames reached by the replay and skipped, per [`FrameFault::ALL`].
    failed: [u64; 3],
    /// Shift from recorded time to replay time (ns), set by `start`.
    shift_ns: i64,
    /// Duration of one loop (ns).
    period_ns: i64,
    /// `seq` advance of one loop (last seq - first seq + 1).
    seq_span: u64,
    next: usize,
    loops: i64,
    emitted: u64,
    encoders: EncoderReplay,
}

/// The session's encoder stream, replayed on the same shifted clock as the frames (it feeds the time
/// alignment stage, which runs on another thread than the frame source).
#[derive(Debug, Clone)]
pub struct EncoderReplay {
    records: Vec<EncoderRecord>,
    shift_ns: i64,
    period_ns: i64,
    next: usize,
    loops: i64,
}

impl EncoderReplay {
    /// Feeds both eyes' tracks with every encoder sample stamped up to `t_ns` (replay time). Refused samples
    /// are counted by the tracks.
    pub fn feed(&mut self, t_ns: i64, tracks: &mut [EncoderTrack; 2]) {
        loop {
            if self.next == self.records.len() {
                self.next = 0;
                self.loops += 1;
            }
            let r = &self.records[self.next];
            let t = r.t_ns + self.shift_ns + self.loops * self.period_ns;
            if t > t_ns {
                break;
            }
            let s = r.sample();
            let _ = tracks[r.eye as usize].push(EncoderSample { t_s: t as f64 * 1e-9, theta_deg: s.theta_deg });
            self.next += 1;
        }
    }
}

impl ReplaySource {
    pub fn open(session: Session) -> Result<ReplaySource> {
        let mut slots = Vec::with_capacity(session.frames.len());
        let mut bad_frames = Vec::new();
        let (w, h) = (session.meta.width, session.meta.height);
        for r in &session.frames {
            let load = |rel: &str| -> std::result::Result<Vec<u8>, (FrameFault, String)> {
                let p = session.path(rel);
                let img = image::open(&p)
                    .map_err(|e| {
                        let missing =
                            matches!(&e, image::ImageError::IoError(io) if io.kind() == std::io::ErrorKind::NotFound);
                        (if missing { FrameFault::Missing } else { FrameFault::Unreadable }, e.to_string())
                    })?
                    .into_luma8();
                if img.width() != w || img.height() != h {
                    return Err((
                        FrameFault::WrongSize,
                        format!("{}x{} image, the session says {w}x{h}", img.width(), img.height()),
                    ));
                }
                Ok(img.into_raw())
            };
            let frame = match (load(&r.left), load(&r.right)) {
                (Ok(left), Ok(right)) => Ok(Decoded { left, right }),
                (l, rr) => {
                    let mut fault = None;
                    for (rel, res) in [(&r.left, l), (&r.right, rr)] {
                        if let Err((f, e)) = res {
                            fault.get_or_insert(f);
                            bad_frames.push((session.path(rel), e));
                        }
                    }
                    Err(fault.expect("one side failed"))
                }
            };
            slots.push(Slot { seq: r.seq, t_start_ns: r.t_start_ns, exposure_ns: r.exposure_ns, frame });
        }
        if !slots.iter().any(|s| s.frame.is_ok()) {
            return Err(RuntimeError::File {
                path: session.dir.join("frames.csv"),
                line: None,
                msg: format!("no readable frame pair ({} unreadable files)", bad_frames.len()),
            });
        }
        // times and seq from the session's rows, readable or not: a bad frame changes neither
        let mut encoders = session.encoders.clone();
        encoders.sort_by_key(|e| (e.t_ns, e.eye));
        let (first, last) = (&session.frames[0], &session.frames[session.frames.len() - 1]);
        let t_first = first.t_start_ns.min(encoders[0].t_ns);
        let t_last = last.t_start_ns.max(encoders.last().map(|e| e.t_ns).unwrap_or(0));
        let period_ns = session.meta.loop_period_ns.unwrap_or(t_last - t_first + (1e9 / session.meta.fps) as i64);
        let seq_span = last.seq - first.seq + 1;
        Ok(ReplaySource {
            session,
            slots,
            bad_frames,
            failed: [0; 3],
            shift_ns: 0,
            period_ns,
            seq_span,
            next: 0,
            loops: 0,
            emitted: 0,
            encoders: EncoderReplay { records: encoders, shift_ns: 0, period_ns, next: 0, loops: 0 },
        })
    }

    /// Rows of frames.csv (readable or not).
    pub fn frames_in_session(&self) -> usize {
        self.slots.len()
    }

    pub fn size(&self) -> (u32, u32) {
        (self.session.meta.width, self.session.meta.height)
    }

    /// Frames reached and skipped so far, by reason.
    pub fn frames_failed(&self) -> impl Iterator<Item = (&'static str, u64)> + '_ {
        FrameFault::ALL.iter().zip(self.failed).filter(|(_, n)| *n > 0).map(|(f, n)| (f.reason(), n))
    }

    /// Anchors recorded time to `now_ns` (CLOCK_MONOTONIC): the session's first frame starts its exposure
    /// then. Returns the encoder stream on the same clock.
    pub fn start(&mut self, now_ns: i64) -> EncoderReplay {
        self.shift_ns = now_ns - self.slots[0].t_start_ns;
        self.next = 0;
        self.loops = 0;
        self.emitted = 0;
        self.failed = [0; 3];
        EncoderReplay { shift_ns: self.shift_ns, next: 0, loops: 0, ..self.encoders.clone() }
    }

    fn loop_shift(&self, loops: i64) -> i64 {
        self.shift_ns + loops * self.period_ns
    }

    /// The next pair (looping), or `None` once `limit` rows were reached (`None` limit: one pass). Rows
    /// whose frame cannot be replayed count towards the limit and in [`ReplaySource::frames_failed`].
    pub fn next_frame(&mut self, limit: Option<u64>) -> Option<ReplayFrame<'_>> {
        let limit = limit.unwrap_or(self.slots.len() as u64);
        loop {
            if self.emitted >= limit {
                return None;
            }
            if self.next == self.slots.len() {
                self.next = 0;
                self.loops += 1;
            }
            let i = self.next;
            self.next += 1;
            self.emitted += 1;
            let shift = self.loop_shift(self.loops);
            let s = &self.slots[i];
            match &s.frame {
                Err(fault) => self.failed[*fault as usize] += 1,
                Ok(f) => {
                    return Some(ReplayFrame {
                        session_seq: s.seq,
                        seq: s.seq + self.loops as u64 * self.seq_span,
                        t_start_ns: s.t_start_ns + shift,
                        right_t_start_ns: s.t_start_ns + shift,
                        exposure_ns: s.exposure_ns,
                        left: &f.left,
                        right: &f.right,
                    })
                }
            }
        }
    }
}
