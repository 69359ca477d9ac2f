//! Replay source: a recorded session played back as if live.
//!
//! Frames are decoded once at start-up (sessions are short; decoding per frame would allocate and cost more
//! than the pipeline), then copied into the pipeline's pooled buffers. Timestamps are shifted onto this
//! process's CLOCK_MONOTONIC so latency means the same as live; when more frames are asked for than the
//! session holds it loops, with timestamps (frames and encoders) kept increasing. A frame file that cannot be
//! decoded is reported by path, counted and skipped: the rest of the session still plays.
use std::path::PathBuf;

use crate::error::{Result, RuntimeError};
use crate::session::{EncoderRecord, Session};
use crate::tasks::align::{EncoderSample, EncoderTrack};

/// A decoded stereo frame of the session.
struct Decoded {
    seq: u64,
    t_start_ns: i64,
    exposure_ns: i64,
    left: Vec<u8>,
    right: Vec<u8>,
}

/// What the replay hands the pipeline for one pair (written into pooled buffers).
pub struct ReplayFrame<'a> {
    /// Index of the pair in the session (before looping).
    pub index: usize,
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
    frames: Vec<Decoded>,
    /// Frames that could not be decoded: (path, reason).
    pub bad_frames: Vec<(PathBuf, String)>,
    /// Shift from recorded time to replay time (ns), set by `start`.
    shift_ns: i64,
    /// Duration of one loop (ns).
    period_ns: i64,
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
        let mut frames = Vec::with_capacity(session.frames.len());
        let mut bad_frames = Vec::new();
        let (w, h) = (session.meta.width, session.meta.height);
        for r in &session.frames {
            let load = |rel: &str| -> std::result::Result<Vec<u8>, String> {
                let p = session.path(rel);
                let img = image::open(&p).map_err(|e| e.to_string())?.into_luma8();
                if img.width() != w || img.height() != h {
                    return Err(format!("{}x{} image, the session says {w}x{h}", img.width(), img.height()));
                }
                Ok(img.into_raw())
            };
            match (load(&r.left), load(&r.right)) {
                (Ok(left), Ok(right)) => frames.push(Decoded {
                    seq: r.seq,
                    t_start_ns: r.t_start_ns,
                    exposure_ns: r.exposure_ns,
                    left,
                    right,
                }),
                (l, rr) => {
                    if let Err(e) = l {
                        bad_frames.push((session.path(&r.left), e));
                    }
                    if let Err(e) = rr {
                        bad_frames.push((session.path(&r.right), e));
                    }
                }
            }
        }
        if frames.is_empty() {
            return Err(RuntimeError::File {
                path: session.dir.join("frames.csv"),
                line: None,
                msg: format!("no readable frame pair ({} unreadable files)", bad_frames.len()),
            });
        }
        let mut encoders = session.encoders.clone();
        encoders.sort_by_key(|e| (e.t_ns, e.eye));
        let t_first = frames[0].t_start_ns.min(encoders[0].t_ns);
        let t_last = frames.last().map(|f| f.t_start_ns).unwrap_or(0).max(encoders.last().map(|e| e.t_ns).unwrap_or(0));
        let period_ns = session.meta.loop_period_ns.unwrap_or(t_last - t_first + (1e9 / session.meta.fps) as i64);
        Ok(ReplaySource {
            session,
            frames,
            bad_frames,
            shift_ns: 0,
            period_ns,
            next: 0,
            loops: 0,
            emitted: 0,
            encoders: EncoderReplay { records: encoders, shift_ns: 0, period_ns, next: 0, loops: 0 },
        })
    }

    pub fn frames_in_session(&self) -> usize {
        self.frames.len()
    }

    pub fn size(&self) -> (u32, u32) {
        (self.session.meta.width, self.session.meta.height)
    }

    /// Anchors recorded time to `now_ns` (CLOCK_MONOTONIC): the first frame starts its exposure then.
    /// Returns the encoder stream on the same clock.
    pub fn start(&mut self, now_ns: i64) -> EncoderReplay {
        self.shift_ns = now_ns - self.frames[0].t_start_ns;
        self.next = 0;
        self.loops = 0;
        self.emitted = 0;
        EncoderReplay { shift_ns: self.shift_ns, next: 0, loops: 0, ..self.encoders.clone() }
    }

    fn loop_shift(&self, loops: i64) -> i64 {
        self.shift_ns + loops * self.period_ns
    }

    /// The next pair (looping), or `None` once `limit` pairs were emitted (`None` limit: one pass).
    pub fn next_frame(&mut self, limit: Option<u64>) -> Option<ReplayFrame<'_>> {
        let limit = limit.unwrap_or(self.frames.len() as u64);
        if self.emitted >= limit {
            return None;
        }
        if self.next == self.frames.len() {
            self.next = 0;
            self.loops += 1;
        }
        let shift = self.loop_shift(self.loops);
        let i = self.next;
        self.next += 1;
        self.emitted += 1;
        let f = &self.frames[i];
        Some(ReplayFrame {
            index: i,
            seq: f.seq + self.loops as u64 * self.frames.len() as u64,
            t_start_ns: f.t_start_ns + shift,
            right_t_start_ns: f.t_start_ns + shift,
            exposure_ns: f.exposure_ns,
            left: &f.left,
            right: &f.right,
        })
    }
}
