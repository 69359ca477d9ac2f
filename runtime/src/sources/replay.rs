//! Replay source: a recorded session played back as if live.
//!
//! Frames are streamed: a decode-ahead thread reads and decodes the PNG files of the rows in order (looping)
//! into a small ring of [`RING`] pre-allocated pairs, at most that many ahead of the pipeline, so a session
//! of any length replays in the same memory: the ring, plus the session's index (frames.csv and encoders.csv
//! rows, about 80 kB per second of recording at 1 kHz encoders). The decoded pair is copied into the
//! pipeline's pooled buffers and its ring slot goes back to the decoder. Timestamps are shifted onto this
//! process's CLOCK_MONOTONIC so latency means the same as live; when more frames are asked for than the
//! session holds it loops, with timestamps (frames and encoders) kept increasing.
//!
//! Every row of frames.csv keeps its identity: its `seq` (ground truth is looked up by it) and its time (the
//! encoders are). A frame whose file is missing, unreadable or of the wrong size is reported by path when the
//! replay first reaches it and counted in `frames_failed` with its reason each time the replay reaches it; it
//! shifts nothing. A decoder that delivers nothing for [`ReplaySource::stall_timeout`] (a file that never
//! finishes reading: a hung network mount, a FIFO) ends the replay with the reason, in `source_ended`.
//!
//! The decode-ahead thread allocates (the PNG decoder's state, per file); the pipeline's threads do not: the
//! ring's pairs circulate between the two. [`on_decode_thread`] tells an allocation counter which thread is
//! the decoder.
use std::cell::Cell;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use crossbeam_channel::{bounded, Receiver, RecvTimeoutError, Select, Sender};

use abvs_runtime_core::error::{Result, RuntimeError};
use abvs_runtime_core::messages::{EncoderSample, SourcePair};
use abvs_runtime_core::session::{EncoderRecord, FrameRecord, Session, SessionMeta};
use abvs_runtime_core::source::{EncoderFeed, PairSource};
use abvs_runtime_core::stats::RunStats;

/// Stereo pairs decoded ahead of the pipeline (each holds both images: 4 x 2 x 1.9 MB at 1600x1200).
pub const RING: usize = 4;

/// How long the replay waits for the decoder before it ends as stalled (decoding a pair takes milliseconds).
pub const STALL_TIMEOUT: Duration = Duration::from_secs(5);

thread_local! {
    static DECODE_THREAD: Cell<bool> = const { Cell::new(false) };
}

/// Whether the calling thread is a replay's decode-ahead thread (it reads and decodes frame files, and
/// allocates doing so; the pipeline's own threads do not). Never allocates: an allocator may call it.
pub fn on_decode_thread() -> bool {
    DECODE_THREAD.try_with(|c| c.get()).unwrap_or(false)
}

/// One decoded stereo pair: a slot of the ring.
struct Pair {
    left: Vec<u8>,
    right: Vec<u8>,
}

/// What the decoder hands over for one row of frames.csv, in row order.
struct Decoded {
    row: usize,
    frame: std::result::Result<Pair, FrameFault>,
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
    /// Every fault, in the order of the statistics.
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

/// What the replay hands the pipeline for one pair (the name it had before sources shared the message).
pub type ReplayFrame<'a> = SourcePair<'a>;

/// The running decode-ahead thread, seen from the replay.
struct Decoder {
    rx: Receiver<Decoded>,
    /// Ring slots going back to the decoder.
    back: Sender<Pair>,
}

/// Files that could not be used, each once: (path, reason). Shared with the decoder, which finds them.
type BadFrames = Arc<Mutex<Vec<(PathBuf, String)>>>;

/// A recorded session replayed as a [`PairSource`]: frames decoded ahead on a thread of their own, times shifted to the run's clock, the session looped when more frames are asked for.
pub struct ReplaySource {
    dir: PathBuf,
    meta: SessionMeta,
    /// Rolling-shutter readout of the frames (ns): session.toml's, or the run's override.
    readout_ns: i64,
    /// The rows of frames.csv, in order (shared with the decoder).
    rows: Arc<[FrameRecord]>,
    bad: BadFrames,
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
    /// Pairs delivered in the current pass (a pass with none ends a replay instead of spinning).
    delivered_this_pass: u64,
    encoders: EncoderReplay,
    decoder: Option<Decoder>,
    /// The pair handed out last (its slot goes back to the ring on the next call).
    current: Option<Pair>,
    /// How long to wait for the decoder before the replay ends as stalled.
    pub stall_timeout: Duration,
    /// Why the replay ended early, if it did (a stalled decoder, a pass without one readable frame).
    pub ended: Option<String>,
}

/// The session's encoder stream, replayed on the same shifted clock as the frames (it feeds the time
/// alignment stage, which runs on another thread than the frame source).
#[derive(Debug, Clone)]
pub struct EncoderReplay {
    records: Arc<[EncoderRecord]>,
    shift_ns: i64,
    period_ns: i64,
    next: usize,
    loops: i64,
}

impl EncoderReplay {
    /// Hands `push` every encoder sample stamped up to `t_ns` (replay time), with its eye.
    pub fn feed(&mut self, t_ns: i64, push: &mut dyn FnMut(usize, EncoderSample)) {
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
            push(r.eye as usize, EncoderSample { t_s: t as f64 * 1e-9, theta_deg: s.theta_deg });
            self.next += 1;
        }
    }
}

/// Decodes one frame file into `buf` (8-bit gray, `size`), or says why it cannot.
fn decode_into(path: &Path, size: (u32, u32), buf: &mut [u8]) -> std::result::Result<(), (FrameFault, String)> {
    use image::ImageDecoder;
    let unreadable = |e: &dyn std::fmt::Display| (FrameFault::Unreadable, e.to_string());
    let reader = image::ImageReader::open(path).map_err(|e| {
        (
            if e.kind() == std::io::ErrorKind::NotFound { FrameFault::Missing } else { FrameFault::Unreadable },
            e.to_string(),
        )
    })?;
    let decoder =
        reader.with_guessed_format().map_err(|e| unreadable(&e))?.into_decoder().map_err(|e| unreadable(&e))?;
    let (w, h) = decoder.dimensions();
    if (w, h) != size {
        return Err((FrameFault::WrongSize, format!("{w}x{h} image, the session says {}x{}", size.0, size.1)));
    }
    if decoder.color_type() == image::ColorType::L8 {
        // straight into the ring slot
        decoder.read_image(buf).map_err(|e| unreadable(&e))
    } else {
        let img = image::DynamicImage::from_decoder(decoder).map_err(|e| unreadable(&e))?.into_luma8();
        buf.copy_from_slice(img.as_raw());
        Ok(())
    }
}

/// The decode-ahead thread: every row in order, looping, until the replay hangs up.
fn decode_ahead(
    dir: PathBuf,
    rows: Arc<[FrameRecord]>,
    size: (u32, u32),
    tx: Sender<Decoded>,
    slots: Receiver<Pair>,
    bad: BadFrames,
) {
    DECODE_THREAD.with(|c| c.set(true));
    let mut spare: Option<Pair> = None;
    for row in (0..rows.len()).cycle() {
        let Some(mut pair) = spare.take().or_else(|| slots.recv().ok()) else { return };
        let r = &rows[row];
        let mut fault = None;
        for (rel, buf) in [(&r.left, &mut pair.left), (&r.right, &mut pair.right)] {
            let path = dir.join(rel);
            if let Err((f, e)) = decode_into(&path, size, buf) {
                fault.get_or_insert(f);
                let mut bad = bad.lock().unwrap_or_else(|p| p.into_inner());
                if !bad.iter().any(|(p, _)| *p == path) {
                    log::warn!("skipped unreadable frame {}: {e}", path.display());
                    bad.push((path, e));
                }
            }
        }
        let frame = match fault {
            None => Ok(pair),
            Some(f) => {
                spare = Some(pair);
                Err(f)
            }
        };
        if tx.send(Decoded { row, frame }).is_err() {
            return;
        }
    }
}

impl ReplaySource {
    /// Takes the session's index (its frame and encoder rows move into the replay); frame files are read
    /// when the replay reaches them.
    pub fn open(mut session: Session) -> Result<ReplaySource> {
        if session.frames.is_empty() || session.encoders.is_empty() {
            return Err(RuntimeError::File {
                path: session.dir.join(if session.frames.is_empty() { "frames.csv" } else { "encoders.csv" }),
                line: None,
                msg: "no rows".into(),
            });
        }
        let rows: Arc<[FrameRecord]> = std::mem::take(&mut session.frames).into();
        // one frame has to be there before a replay starts (the others are checked when reached)
        let size = (session.meta.width, session.meta.height);
        let mut buf = vec![0u8; (size.0 * size.1) as usize];
        let mut errors = Vec::new();
        let readable = rows.iter().any(|r| {
            [&r.left, &r.right].iter().all(|rel| match decode_into(&session.dir.join(rel), size, &mut buf) {
                Ok(()) => true,
                Err((_, e)) => {
                    errors.push(format!("{rel}: {e}"));
                    false
                }
            })
        });
        if !readable {
            return Err(RuntimeError::File {
                path: session.dir.join("frames.csv"),
                line: None,
                msg: format!("no readable frame pair ({} unreadable files: {})", errors.len(), errors.join("; ")),
            });
        }
        // times and seq from the session's rows, readable or not: a bad frame changes neither
        let mut encoders = std::mem::take(&mut session.encoders);
        encoders.sort_by_key(|e| (e.t_ns, e.eye));
        let (first, last) = (&rows[0], &rows[rows.len() - 1]);
        let t_first = first.t_start_ns.min(encoders[0].t_ns);
        let t_last = last.t_start_ns.max(encoders.last().map(|e| e.t_ns).unwrap_or(0));
        let period_ns = session.meta.loop_period_ns.unwrap_or(t_last - t_first + (1e9 / session.meta.fps) as i64);
        let seq_span = last.seq - first.seq + 1;
        Ok(ReplaySource {
            dir: session.dir,
            readout_ns: (session.meta.readout_ms * 1e6).round() as i64,
            meta: session.meta,
            rows,
            bad: Arc::default(),
            failed: [0; 3],
            shift_ns: 0,
            period_ns,
            seq_span,
            next: 0,
            loops: 0,
            emitted: 0,
            delivered_this_pass: 0,
            encoders: EncoderReplay { records: encoders.into(), shift_ns: 0, period_ns, next: 0, loops: 0 },
            decoder: None,
            current: None,
            stall_timeout: STALL_TIMEOUT,
            ended: None,
        })
    }

    /// The session's metadata (session.toml).
    pub fn meta(&self) -> &SessionMeta {
        &self.meta
    }

    /// Overrides session.toml's rolling-shutter readout (ns), e.g. to replay with wrong timing on purpose.
    pub fn set_readout_ns(&mut self, readout_ns: i64) {
        self.readout_ns = readout_ns.max(0);
    }

    /// The readout the frames are handed out with (ns).
    pub fn readout_ns(&self) -> i64 {
        self.readout_ns
    }

    /// The session's directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Rows of frames.csv (readable or not).
    pub fn frames_in_session(&self) -> usize {
        self.rows.len()
    }

    /// Raw frame size (both eyes).
    pub fn size(&self) -> (u32, u32) {
        (self.meta.width, self.meta.height)
    }

    /// Frame files found unusable so far (each once): path and reason.
    pub fn bad_frames(&self) -> Vec<(PathBuf, String)> {
        self.bad.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }

    /// Frames reached and skipped so far, by reason.
    pub fn frames_failed(&self) -> impl Iterator<Item = (&'static str, u64)> + '_ {
        FrameFault::ALL.iter().zip(self.failed).filter(|(_, n)| *n > 0).map(|(f, n)| (f.reason(), n))
    }

    /// Anchors recorded time to `now_ns` (CLOCK_MONOTONIC): the session's first frame starts its exposure
    /// then. Starts decoding ahead from the first row. Returns the encoder stream on the same clock.
    pub fn start(&mut self, now_ns: i64) -> EncoderReplay {
        self.shift_ns = now_ns - self.rows[0].t_start_ns;
        self.next = 0;
        self.loops = 0;
        self.emitted = 0;
        self.delivered_this_pass = 0;
        self.failed = [0; 3];
        self.ended = None;
        self.spawn_decoder();
        EncoderReplay { shift_ns: self.shift_ns, next: 0, loops: 0, ..self.encoders.clone() }
    }

    /// (Re)starts the decode-ahead thread at the first row, with a fresh ring. A previous decoder is hung
    /// up on (it ends at its next send or receive; it is not joined, as it may be blocked in a read).
    fn spawn_decoder(&mut self) {
        self.decoder = None;
        self.current = None;
        let (tx, rx) = bounded::<Decoded>(RING);
        let (back, slots) = bounded::<Pair>(RING);
        let n = (self.meta.width * self.meta.height) as usize;
        for _ in 0..RING {
            back.send(Pair { left: vec![0; n], right: vec![0; n] }).expect("the ring has room");
        }
        // crossbeam allocates a channel's list of waiting receivers the first time one waits: take that
        // allocation here, not on the pipeline's source thread (a zero-timeout select registers and gives up)
        let mut sel = Select::new();
        sel.recv(&rx);
        let _ = sel.select_timeout(Duration::ZERO);
        let (dir, rows, bad, size) = (self.dir.clone(), self.rows.clone(), self.bad.clone(), self.size());
        std::thread::Builder::new()
            .name("abvs-replay-decode".into())
            .spawn(move || decode_ahead(dir, rows, size, tx, slots, bad))
            .expect("spawning the replay's decode-ahead thread");
        self.decoder = Some(Decoder { rx, back });
    }

    fn loop_shift(&self, loops: i64) -> i64 {
        self.shift_ns + loops * self.period_ns
    }

    /// The next pair (looping), or `None` once `limit` rows were reached (`None` limit: one pass), or when
    /// the replay ended early ([`ReplaySource::ended`] says why). Rows whose frame cannot be replayed count
    /// towards the limit and in [`ReplaySource::frames_failed`].
    pub fn next_frame(&mut self, limit: Option<u64>) -> Option<SourcePair<'_>> {
        let limit = limit.unwrap_or(self.rows.len() as u64);
        if self.decoder.is_none() {
            // not started: recorded time as is
            self.spawn_decoder();
        }
        let dec = self.decoder.as_ref().expect("decoder running");
        if let Some(p) = self.current.take() {
            let _ = dec.back.send(p);
        }
        loop {
            if self.emitted >= limit || self.ended.is_some() {
                return None;
            }
            if self.next == self.rows.len() {
                if self.delivered_this_pass == 0 {
                    self.ended = Some(format!("a whole pass of {} rows without one readable frame", self.rows.len()));
                    return None;
                }
                self.next = 0;
                self.loops += 1;
                self.delivered_this_pass = 0;
            }
            let d = match dec.rx.recv_timeout(self.stall_timeout) {
                Ok(d) => d,
                Err(RecvTimeoutError::Timeout) => {
                    self.ended = Some(format!(
                        "stalled: no frame decoded within {:.1} s (row {}: {})",
                        self.stall_timeout.as_secs_f64(),
                        self.next,
                        self.rows[self.next].left
                    ));
                    return None;
                }
                Err(RecvTimeoutError::Disconnected) => {
                    self.ended = Some("the decode-ahead thread ended".into());
                    return None;
                }
            };
            let i = self.next;
            debug_assert_eq!(d.row, i, "the decoder delivers rows in order");
            self.next += 1;
            self.emitted += 1;
            match d.frame {
                Err(fault) => self.failed[fault as usize] += 1,
                Ok(pair) => {
                    self.delivered_this_pass += 1;
                    let shift = self.loop_shift(self.loops);
                    let s = &self.rows[i];
                    let p = self.current.insert(pair);
                    return Some(SourcePair {
                        session_seq: s.seq,
                        seq: s.seq + self.loops as u64 * self.seq_span,
                        t_start_ns: s.t_start_ns + shift,
                        right_t_start_ns: s.t_start_ns + shift,
                        exposure_ns: s.exposure_ns,
                        readout_ns: self.readout_ns,
                        readout_anchor: 0.0,
                        left: &p.left,
                        right: &p.right,
                    });
                }
            }
        }
    }
}
// ---- as the graph's source

impl PairSource for ReplaySource {
    fn size(&self) -> (u32, u32) {
        ReplaySource::size(self)
    }
    fn start(&mut self, now_ns: i64) -> Box<dyn EncoderFeed> {
        Box::new(ReplaySource::start(self, now_ns))
    }
    fn next_frame(&mut self, limit: Option<u64>) -> Option<SourcePair<'_>> {
        ReplaySource::next_frame(self, limit)
    }
    fn finish(&mut self, stats: &mut RunStats) {
        stats.extra.insert("bad_frame_files".into(), serde_json::json!(self.bad_frames().len()));
        if let Some(e) = &self.ended {
            stats.extra.insert("source_ended".into(), serde_json::json!(e));
        }
        // frames the replay reached but could not read: in, and failed with their reason
        for (reason, n) in self.frames_failed() {
            stats.frames_in += n;
            *stats.frames_failed.entry(reason.to_string()).or_default() += n;
        }
    }
}

impl EncoderFeed for EncoderReplay {
    fn feed(&mut self, t_ns: i64, push: &mut dyn FnMut(usize, EncoderSample)) {
        EncoderReplay::feed(self, t_ns, push)
    }
}
