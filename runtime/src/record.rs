//! Recording a session from live sources (`abvs record`): the stereo capture and the encoder
//! stream -> [`SessionWriter`], on two threads (this one pairs and routes, a writer thread
//! encodes PNGs), so that slow disks drop whole pairs (counted) instead of stalling the cameras.
//!
//! Nothing is recorded before both eyes are homed: frames before that are counted, encoder
//! samples before that are consumed by homing. After the last pair the encoders are recorded a
//! little longer, so the last frame's mid-exposure is covered for interpolation.
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use abvs_board::stream::EncoderStream;
use abvs_board::tracker::EncoderStats;
use crossbeam_channel::{bounded, Receiver, Sender, TrySendError};
use serde::Serialize;

use crate::sinks::session_writer::SessionWriter;
use crate::sources::live::encoder_record;
use crate::sources::v4l_capture::{CaptureError, StereoCapture, StereoStats};
use abvs_runtime_core::error::{Result, RuntimeError};
use abvs_runtime_core::messages::FramePair;
use abvs_runtime_core::session::{EncoderRecord, Session};

/// How a recording runs: when it stops, how long homing and the capture may take, the writer's queue.
#[derive(Debug, Clone)]
pub struct RecordConfig {
    /// Stop after this many pairs written.
    pub frames: Option<u64>,
    /// Stop after this long (from the start, homing included).
    pub duration: Option<Duration>,
    /// Both eyes must be homed within this time from the start.
    pub homing_timeout: Duration,
    /// A capture that delivers no pair for this long is an error.
    pub pair_timeout: Duration,
    /// Pairs waiting for the writer; beyond this the newest pair is dropped (counted).
    pub queue: usize,
    /// Encoders recorded after the last pair.
    pub tail: Duration,
}

impl Default for RecordConfig {
    fn default() -> Self {
        RecordConfig {
            frames: None,
            duration: None,
            homing_timeout: Duration::from_secs(30),
            pair_timeout: Duration::from_secs(2),
            queue: 16,
            tail: Duration::from_millis(200),
        }
    }
}

/// What happened during a recording.
#[derive(Debug, Clone, Default, Serialize)]
pub struct RecordStats {
    /// Pairs the capture delivered.
    pub pairs_in: u64,
    /// Pairs written into the session.
    pub pairs_written: u64,
    /// Pairs delivered before both eyes were homed (not recorded).
    pub pairs_before_homing: u64,
    /// Pairs dropped because the writer was behind.
    pub pairs_dropped_writer: u64,
    /// Pairs the writer failed on (disk full, ...): not in the session.
    pub pairs_write_failed: u64,
    /// Writes that failed (pairs and batches of encoder rows; disk full, ...); the last error is kept.
    pub write_errors: u64,
    /// The last write error.
    pub last_write_error: Option<String>,
    /// Encoder rows written.
    pub encoder_rows: u64,
    /// The capture's pairing counts and errors.
    pub capture: StereoStats,
    /// The encoder stream's counts (link, homing).
    pub encoders: EncoderStats,
    /// The error that ended the encoder stream early, if one did.
    pub encoder_error: Option<String>,
    /// Seconds from the start until both eyes were homed.
    pub homed_after_s: Option<f64>,
    /// Seconds the recording took.
    pub elapsed_s: f64,
}

enum ToWriter {
    Pair(FramePair),
    Encoders(Vec<EncoderRecord>),
}

struct WriterEnd {
    writer: SessionWriter,
    errors: u64,
    last_error: Option<String>,
}

/// A pair back from the writer (for recycling), and whether it was written.
type Written = (FramePair, bool);

fn spawn_writer(
    mut writer: SessionWriter,
    rx: Receiver<ToWriter>,
    done: Sender<Written>,
) -> std::thread::JoinHandle<WriterEnd> {
    std::thread::Builder::new()
        .name("session-writer".into())
        .spawn(move || {
            let (mut errors, mut last_error) = (0u64, None);
            for msg in rx {
                let r = match msg {
                    ToWriter::Pair(pair) => {
                        let r = writer.write_pair(&pair);
                        let _ = done.try_send((pair, r.is_ok()));
                        r
                    }
                    ToWriter::Encoders(rows) => writer.write_encoders(&rows),
                };
                if let Err(e) = r {
                    errors += 1;
                    last_error = Some(e.to_string());
                }
            }
            WriterEnd { writer, errors, last_error }
        })
        .expect("spawning the session writer")
}

/// Records until `cfg` says stop or `stop` is set (Ctrl-C). Returns the written session (it opens
/// with [`Session::open`]), or the failure that ended the recording (capture, homing, encoder
/// port), and the counts either way; what was recorded before a failure is finished on disk.
pub fn record(
    capture: &mut StereoCapture,
    encoders: EncoderStream,
    writer: SessionWriter,
    cfg: &RecordConfig,
    stop: &AtomicBool,
    progress: &mut dyn FnMut(&RecordStats),
) -> (Result<Session>, RecordStats) {
    let start = Instant::now();
    let (tx, rx) = bounded::<ToWriter>(cfg.queue.max(1));
    let (done_tx, done_rx) = bounded::<Written>(cfg.queue.max(1) + 2);
    let writer_thread = spawn_writer(writer, rx, done_tx);
    let mut stats = RecordStats::default();
    let mut failure: Option<RuntimeError> = None;
    // Pairs handed to the writer (written or failing there): what --frames counts.
    let mut queued = 0u64;

    // Encoder rows never drop: they go through a blocking send (the writer only appends CSV).
    let forward_encoders = |tx: &Sender<ToWriter>, stats: &mut RecordStats| {
        let rows: Vec<EncoderRecord> = encoders.records().try_iter().map(|h| encoder_record(&h)).collect();
        if !rows.is_empty() {
            stats.encoder_rows += rows.len() as u64;
            let _ = tx.send(ToWriter::Encoders(rows));
        }
    };

    loop {
        if stop.load(Ordering::Relaxed)
            || cfg.frames.is_some_and(|n| queued + stats.pairs_dropped_writer >= n)
            || cfg.duration.is_some_and(|d| start.elapsed() >= d)
        {
            break;
        }
        for (pair, ok) in done_rx.try_iter() {
            stats.pairs_written += u64::from(ok);
            stats.pairs_write_failed += u64::from(!ok);
            capture.recycle(pair);
        }
        forward_encoders(&tx, &mut stats);
        if encoders.is_finished() {
            failure = Some(RuntimeError::Invalid("the encoder stream ended".into()));
            break;
        }
        let homed = encoders.homed();
        if stats.homed_after_s.is_none() {
            if homed == [true, true] {
                stats.homed_after_s = Some(start.elapsed().as_secs_f64());
            } else if start.elapsed() > cfg.homing_timeout {
                let e = encoders.stats();
                let which: Vec<String> = (0..2)
                    .filter(|&i| !homed[i])
                    .map(|i| {
                        format!(
                            "eye {i} ({} samples{})",
                            e.homing_samples[i],
                            e.last_homing_error[i].as_ref().map(|m| format!(", last refusal: {m}")).unwrap_or_default()
                        )
                    })
                    .collect();
                failure = Some(RuntimeError::Invalid(format!(
                    "not homed within {:.0} s: {}",
                    cfg.homing_timeout.as_secs_f64(),
                    which.join("; ")
                )));
                break;
            }
        }
        let pair = match capture.next_pair(cfg.pair_timeout) {
            Ok(p) => p,
            Err(CaptureError::Timeout { .. }) => {
                failure = Some(RuntimeError::Invalid(format!(
                    "no stereo pair for {:.1} s (check both cameras stream and are synchronised)",
                    cfg.pair_timeout.as_secs_f64()
                )));
                break;
            }
            Err(e) => {
                failure = Some(e.into());
                break;
            }
        };
        stats.pairs_in += 1;
        // Homing state as of this pair's arrival (the wait for it may have been long).
        if encoders.homed() != [true, true] {
            // Counted: the links may still be rolling through their markers.
            stats.pairs_before_homing += 1;
            capture.recycle(pair);
            continue;
        }
        match tx.try_send(ToWriter::Pair(pair)) {
            Ok(()) => queued += 1,
            Err(TrySendError::Full(ToWriter::Pair(p)) | TrySendError::Disconnected(ToWriter::Pair(p))) => {
                stats.pairs_dropped_writer += 1;
                capture.recycle(p);
            }
            Err(_) => unreachable!("only pairs are sent here"),
        }
        stats.capture = capture.stats();
        stats.encoders = encoders.stats();
        stats.elapsed_s = start.elapsed().as_secs_f64();
        progress(&stats);
    }

    // The tail: encoders a little past the last frame, then the encoder thread stops.
    let tail_end = Instant::now() + cfg.tail;
    while Instant::now() < tail_end && !encoders.is_finished() {
        forward_encoders(&tx, &mut stats);
        std::thread::sleep(Duration::from_millis(10));
    }
    forward_encoders(&tx, &mut stats);
    let rest: Vec<EncoderRecord> = encoders.records().try_iter().map(|h| encoder_record(&h)).collect();
    let (enc_stats, enc_err) = encoders.finish();
    if !rest.is_empty() {
        stats.encoder_rows += rest.len() as u64;
        let _ = tx.send(ToWriter::Encoders(rest));
    }
    drop(tx);
    let end = match writer_thread.join() {
        Ok(end) => end,
        Err(_) => return (Err(RuntimeError::Panicked("the session writer".into())), stats),
    };
    for (pair, ok) in done_rx.try_iter() {
        stats.pairs_written += u64::from(ok);
        stats.pairs_write_failed += u64::from(!ok);
        capture.recycle(pair);
    }
    stats.write_errors = end.errors;
    stats.last_write_error = end.last_error;
    stats.capture = capture.stats();
    stats.encoders = enc_stats;
    stats.encoder_error = enc_err.map(|e| e.to_string());
    stats.elapsed_s = start.elapsed().as_secs_f64();
    progress(&stats);
    // Finish what was recorded even when the run failed: it is the user's data.
    let session = end.writer.finish();
    match failure {
        Some(e) => (Err(e), stats),
        None => (session, stats),
    }
}
