//! The pipeline: stages on threads joined by bounded crossbeam channels, data flowing one way.
//!
//! ```text
//! source ──q──> rectify (align, FK, extrinsic, maps, remap) ──q──> disparity ──q──> output (depth, cloud, sinks)
//!    ^                                                                                   │
//!    └──────────────────────────── free list of pooled work buffers ─────────────────────┘
//! ```
//! Every frame travels in one pooled [`Work`] item allocated at start-up and returned to the free list at the
//! end, so steady state does not allocate. Under overload a full queue drops its **oldest** item (counted) to
//! make room: latency stays bounded by the queue depths instead of growing. In lossless mode (offline
//! processing, reproducible replays) queues block instead.
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use abvs_camera::Camera;
use crossbeam_channel::{bounded, Receiver, RecvTimeoutError, Select, Sender, TrySendError};

use crate::error::{Result, RuntimeError};
use crate::sinks::stats::{monotonic_ns, rss_bytes, Latency, RunStats, Window};
use crate::sources::replay::{ReplayFrame, ReplaySource};
use crate::tasks::align::EncoderTrack;
use crate::tasks::depth::{DepthConfig, DepthFrame};
use crate::tasks::disparity::DisparityEngine;
use crate::tasks::kinematics::{StereoKinematics, StereoPose};
use crate::tasks::rectify::{Rectification, RectifiedCamera, StereoRectifier};

pub const STAGES: [&str; 4] = ["source", "rectify", "disparity", "output"];

/// One frame's buffers and results as it moves through the stages.
pub struct Work {
    pub seq: u64,
    /// The frame's `seq` in its session (before looping): the key of its ground truth.
    pub session_seq: u64,
    /// Left mid-exposure time (CLOCK_MONOTONIC ns): the frame's timestamp.
    pub t_frame_ns: i64,
    pub t_right_ns: i64,
    pub raw_left: Vec<u8>,
    pub raw_right: Vec<u8>,
    pub rect_left: Vec<u8>,
    pub rect_right: Vec<u8>,
    /// 1 where the rectified left pixel sees the raw image.
    pub valid: Vec<u8>,
    pub disparity: Vec<f32>,
    pub theta: [[f64; 3]; 2],
    pub pose: Option<StereoPose>,
    pub rect: Option<Rectification>,
    /// When each stage started with this frame (ns), for per-stage latency.
    pub t_stage_ns: [i64; 4],
    pub stage_ns: [i64; 4],
}

impl Work {
    fn new(raw: (u32, u32), out: (u32, u32)) -> Box<Work> {
        let nr = (raw.0 * raw.1) as usize;
        let no = (out.0 * out.1) as usize;
        Box::new(Work {
            seq: 0,
            session_seq: 0,
            t_frame_ns: 0,
            t_right_ns: 0,
            raw_left: vec![0; nr],
            raw_right: vec![0; nr],
            rect_left: vec![0; no],
            rect_right: vec![0; no],
            valid: vec![0; no],
            disparity: vec![f32::NAN; no],
            theta: [[0.0; 3]; 2],
            pose: None,
            rect: None,
            t_stage_ns: [0; 4],
            stage_ns: [0; 4],
        })
    }
}

/// What an output sink sees of one finished frame.
pub struct Published<'a> {
    pub seq: u64,
    /// The frame's `seq` in its session (before looping): the key of its ground truth.
    pub session_seq: u64,
    pub t_frame_ns: i64,
    pub theta: &'a [[f64; 3]; 2],
    pub pose: &'a StereoPose,
    pub rect: &'a Rectification,
    pub cam: &'a RectifiedCamera,
    pub depth: &'a DepthFrame,
    pub left_rect: &'a [u8],
    pub right_rect: &'a [u8],
    pub disparity: &'a [f32],
}

/// Where finished frames go: iceoryx2 publishing, ground-truth scoring, PNG dumps.
pub trait Sink: Send {
    fn name(&self) -> &'static str;
    fn consume(&mut self, out: &Published) -> Result<()>;
    /// Adds what the sink measured to the run's statistics.
    fn finish(&mut self, _stats: &mut RunStats) {}
}

#[derive(Debug, Clone, Copy)]
pub struct PipelineConfig {
    pub out: RectifiedCamera,
    /// Node spacing of the rectification map grid (px).
    pub grid_step: u32,
    pub depth: DepthConfig,
    /// Capacity of each inter-stage queue.
    pub queue: usize,
    /// Block instead of dropping: every frame is processed (offline, reproducible).
    pub lossless: bool,
    /// Release replayed frames at their recorded times (as a live camera would).
    pub paced: bool,
    /// Number of frames (looping the session); `None` plays it once.
    pub frames: Option<u64>,
    /// Stop taking frames from the source this long after the start (the frames in flight finish).
    pub duration: Option<Duration>,
    /// Length of a statistics window: latency percentiles, counts and resident memory per window
    /// ([`RunStats::windows`]).
    pub window: Duration,
    /// Stop taking frames once this is set (Ctrl-C, SIGTERM): the frames in flight finish and the run
    /// returns its statistics as at the end of a replay.
    pub stop: Option<&'static AtomicBool>,
}

impl Default for PipelineConfig {
    fn default() -> Self {
        PipelineConfig {
            out: RectifiedCamera::with_hfov(320, 240, 100.0),
            grid_step: 8,
            depth: DepthConfig::default(),
            queue: 2,
            lossless: false,
            paced: true,
            frames: None,
            duration: None,
            window: Duration::from_secs(60),
            stop: None,
        }
    }
}

/// Pushes into a bounded queue; when full, the oldest queued item goes back to the free list (dropped).
fn push(
    tx: &Sender<Box<Work>>,
    rx: &Receiver<Box<Work>>,
    free: &Sender<Box<Work>>,
    w: Box<Work>,
    lossless: bool,
    dropped: &AtomicU64,
) {
    if lossless {
        let _ = tx.send(w);
        return;
    }
    let mut w = w;
    loop {
        match tx.try_send(w) {
            Ok(()) => return,
            Err(TrySendError::Full(back)) => {
                w = back;
                if let Ok(old) = rx.try_recv() {
                    dropped.fetch_add(1, Ordering::Relaxed);
                    let _ = free.send(old);
                }
            }
            Err(TrySendError::Disconnected(_)) => return,
        }
    }
}

/// crossbeam allocates once, lazily, the first time a thread blocks on any channel (its thread-local wait
/// context). Left to chance that can happen hundreds of frames into a run (the first time a stage finds its
/// queue empty), so every stage thread takes that allocation at start-up instead.
fn prewarm_thread() {
    let (_tx, rx) = bounded::<()>(0);
    let _ = rx.recv_timeout(Duration::from_micros(1));
}

/// The other lazy crossbeam allocation: the list of threads waiting on one side of a channel is allocated
/// (capacity 4, kept afterwards) the first time a thread waits there. A `Select` with a zero timeout
/// registers a waiter on every operation that is not ready and then gives up without blocking, so it
/// allocates every list at once: receivers on the empty channels, then senders on the full work queues.
fn prewarm_waiter_lists(
    free: (&Sender<Box<Work>>, &Receiver<Box<Work>>),
    queues: [(&Sender<Box<Work>>, &Receiver<Box<Work>>); 3],
) {
    let mut spare: Vec<Box<Work>> = free.1.try_iter().collect();
    let n = spare.len();
    let mut sel = Select::new();
    sel.recv(free.1);
    for q in &queues {
        sel.recv(q.1);
    }
    // all channels are empty: nothing can be selected, the call only registers and times out
    assert!(sel.select_timeout(Duration::ZERO).is_err(), "pre-warm: an empty queue was ready");
    let mut sel = Select::new();
    for q in &queues {
        while !q.0.is_full() {
            let Some(w) = spare.pop() else { break };
            let _ = q.0.try_send(w);
        }
        sel.send(q.0);
    }
    if queues.iter().all(|q| q.0.is_full()) {
        assert!(sel.select_timeout(Duration::ZERO).is_err(), "pre-warm: a full queue was ready");
    }
    for q in &queues {
        spare.extend(q.1.try_iter());
    }
    assert_eq!(spare.len(), n, "pre-warm lost a buffer");
    for w in spare {
        free.0.send(w).expect("free list has room");
    }
}

/// Scales calibration intrinsics to the frames' size (sensor binning modes keep the lens).
pub fn camera_for_frames(cam: &Camera, w: u32, h: u32) -> Result<Camera> {
    if cam.width == w && cam.height == h {
        return Ok(*cam);
    }
    let ra = cam.width as f64 / cam.height as f64;
    let rb = w as f64 / h as f64;
    if (ra - rb).abs() > 1e-3 {
        return Err(RuntimeError::Invalid(format!(
            "calibration is for {}x{} images, the frames are {w}x{h} (different aspect ratio)",
            cam.width, cam.height
        )));
    }
    Ok(cam.scaled(w, h))
}

/// Where the pipeline's stereo pairs come from: a recorded session ([`ReplaySource`]) or the live
/// cameras ([`crate::sources::live::LiveSource`]).
pub trait PairSource: Send {
    /// Raw frame size (both eyes).
    fn size(&self) -> (u32, u32);
    /// Anchors the source's clock to `now_ns` (CLOCK_MONOTONIC) and hands out its encoder stream,
    /// which the time-alignment stage reads on another thread.
    fn start(&mut self, now_ns: i64) -> Box<dyn EncoderFeed>;
    /// The next pair, or `None` when the source is done (`limit` pairs, end of a replay, capture stopped).
    fn next_frame(&mut self, limit: Option<u64>) -> Option<ReplayFrame<'_>>;
    /// Adds what the source counted (unreadable files, capture drops) to the run's statistics.
    fn finish(&mut self, _stats: &mut RunStats) {}
}

/// The encoder samples of a [`PairSource`], on its clock.
pub trait EncoderFeed: Send {
    /// Pushes every sample stamped up to `t_ns` into the eyes' tracks (a live feed waits briefly
    /// for samples still on the wire).
    fn feed(&mut self, t_ns: i64, tracks: &mut [EncoderTrack; 2]);
}

impl PairSource for ReplaySource {
    fn size(&self) -> (u32, u32) {
        ReplaySource::size(self)
    }
    fn start(&mut self, now_ns: i64) -> Box<dyn EncoderFeed> {
        Box::new(ReplaySource::start(self, now_ns))
    }
    fn next_frame(&mut self, limit: Option<u64>) -> Option<ReplayFrame<'_>> {
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

impl EncoderFeed for crate::sources::replay::EncoderReplay {
    fn feed(&mut self, t_ns: i64, tracks: &mut [EncoderTrack; 2]) {
        crate::sources::replay::EncoderReplay::feed(self, t_ns, tracks)
    }
}

/// Runs a replay through the whole pipeline and returns its statistics.
pub fn run_replay(
    source: ReplaySource,
    kin: StereoKinematics,
    cams: (Camera, Camera),
    engine: Box<dyn DisparityEngine>,
    sinks: Vec<Box<dyn Sink>>,
    cfg: PipelineConfig,
) -> Result<RunStats> {
    // (unusable frame files are reported on stderr as the replay reaches them)
    run(source, kin, cams, engine, sinks, cfg)
}

/// Runs any pair source through the whole pipeline and returns its statistics.
pub fn run<S: PairSource>(
    mut source: S,
    mut kin: StereoKinematics,
    cams: (Camera, Camera),
    mut engine: Box<dyn DisparityEngine>,
    mut sinks: Vec<Box<dyn Sink>>,
    cfg: PipelineConfig,
) -> Result<RunStats> {
    let (rw, rh) = source.size();
    let out = (cfg.out.width, cfg.out.height);
    if engine.size() != out {
        return Err(RuntimeError::Invalid(format!(
            "disparity engine {} runs at {}x{}, the pipeline at {}x{}",
            engine.name(),
            engine.size().0,
            engine.size().1,
            out.0,
            out.1
        )));
    }
    let cam_l = camera_for_frames(&cams.0, rw, rh)?;
    let cam_r = camera_for_frames(&cams.1, rw, rh)?;
    let mut rectifier = StereoRectifier::new(cam_l, cam_r, cfg.out, cfg.grid_step)?;
    let latency =
        |unit: Option<&abvs_eye::UnitModel>| unit.map(|u| u.encoder_time_for_camera(0.0).abs()).unwrap_or(0.0);
    let mut tracks = [EncoderTrack::new(2000), EncoderTrack::new(2000)];
    tracks[0].latency_s = latency(kin.left.unit());
    tracks[1].latency_s = latency(kin.right.unit());

    let q = cfg.queue.max(1);
    // Enough buffers that the source always finds a free one when it takes a frame: the three queues hold
    // at most 3q, rectify and disparity at most 2 each (the frame they push and, while a full queue drops
    // its oldest, that one on its way back to the free list), the output 1, the source none at that moment:
    // 3q + 5 in use, so one is always free and under overload only the oldest queued frames are dropped.
    let pool = 3 * q + 6;
    let (free_tx, free_rx) = bounded::<Box<Work>>(pool);
    for _ in 0..pool {
        free_tx.send(Work::new((rw, rh), out)).expect("free list has room");
    }
    let (q1_tx, q1_rx) = bounded::<Box<Work>>(q);
    let (q2_tx, q2_rx) = bounded::<Box<Work>>(q);
    let (q3_tx, q3_rx) = bounded::<Box<Work>>(q);
    // (the free list's senders never wait: it has room for every buffer)
    prewarm_waiter_lists((&free_tx, &free_rx), [(&q1_tx, &q1_rx), (&q2_tx, &q2_rx), (&q3_tx, &q3_rx)]);
    let dropped = Arc::new(AtomicU64::new(0));
    let frames_in = Arc::new(AtomicU64::new(0));
    let mut stats = RunStats::new(&STAGES);
    let started = monotonic_ns();
    let mut encoders = source.start(started + 5_000_000);

    let result = std::thread::scope(|s| -> Result<()> {
        // ---- source
        let src = {
            let (free_rx, q1_tx, q1_rx, free_tx) = (free_rx.clone(), q1_tx.clone(), q1_rx.clone(), free_tx.clone());
            let (dropped, frames_in) = (dropped.clone(), frames_in.clone());
            let source = &mut source;
            s.spawn(move || -> Latency {
                prewarm_thread();
                let mut lat = Latency::default();
                let end_ns = cfg.duration.map(|d| started.saturating_add(d.as_nanos().min(i64::MAX as u128) as i64));
                loop {
                    if end_ns.is_some_and(|end| monotonic_ns() >= end)
                        || cfg.stop.is_some_and(|s| s.load(Ordering::Relaxed))
                    {
                        break;
                    }
                    let Some(f) = source.next_frame(cfg.frames) else { break };
                    frames_in.fetch_add(1, Ordering::Relaxed);
                    let ready = f.t_start_ns + f.exposure_ns; // a frame exists once its exposure ended
                    if cfg.paced {
                        let wait = ready - monotonic_ns();
                        if wait > 0 {
                            std::thread::sleep(Duration::from_nanos(wait as u64));
                        }
                    }
                    let t0 = monotonic_ns();
                    let mut w = match if cfg.lossless { free_rx.recv().ok() } else { free_rx.try_recv().ok() } {
                        Some(w) => w,
                        None => {
                            // every buffer in flight (cannot happen with the pool's size; a counted guard)
                            dropped.fetch_add(1, Ordering::Relaxed);
                            continue;
                        }
                    };
                    w.seq = f.seq;
                    w.session_seq = f.session_seq;
                    w.t_frame_ns = f.t_start_ns + f.exposure_ns / 2;
                    w.t_right_ns = f.right_t_start_ns + f.exposure_ns / 2;
                    w.raw_left.copy_from_slice(f.left);
                    w.raw_right.copy_from_slice(f.right);
                    w.t_stage_ns = [t0, 0, 0, 0];
                    w.stage_ns[0] = monotonic_ns() - t0;
                    lat.record_ns(w.stage_ns[0]);
                    push(&q1_tx, &q1_rx, &free_tx, w, cfg.lossless, &dropped);
                }
                drop(q1_tx);
                lat
            })
        };
        drop(q1_tx);
        // ---- rectify: time alignment, FK, moving extrinsic, maps, remap
        let rect_stage = {
            let (q1_rx, q2_tx, q2_rx, free_tx) = (q1_rx.clone(), q2_tx.clone(), q2_rx.clone(), free_tx.clone());
            let dropped = dropped.clone();
            let kin = &mut kin;
            let rectifier = &mut rectifier;
            let tracks = &mut tracks;
            let encoders = &mut encoders;
            s.spawn(move || -> (Latency, Vec<&'static str>) {
                prewarm_thread();
                let mut lat = Latency::default();
                let mut failed = Vec::new();
                for mut w in q1_rx.iter() {
                    let t0 = monotonic_ns();
                    let r = (|| -> Result<()> {
                        // encoders up to a little past the frame (interpolation needs the samples after it)
                        let latest = w.t_frame_ns.max(w.t_right_ns) + 20_000_000;
                        encoders.feed(latest + (tracks[0].latency_s.max(tracks[1].latency_s) * 1e9) as i64, tracks);
                        w.theta[0] = tracks[0].at_camera_time(w.t_frame_ns as f64 * 1e-9)?;
                        w.theta[1] = tracks[1].at_camera_time(w.t_right_ns as f64 * 1e-9)?;
                        let pose = kin.solve(&w.theta[0], &w.theta[1])?;
                        let rect = rectifier.update(&pose.left_to_right)?;
                        let (rw, rh) = (rectifier.cam_left.width, rectifier.cam_left.height);
                        rectifier.left.remap(&w.raw_left, rw, rh, &mut w.rect_left)?;
                        rectifier.right.remap(&w.raw_right, rw, rh, &mut w.rect_right)?;
                        for (v, x) in w.valid.iter_mut().zip(rectifier.left.map_x()) {
                            *v = (*x >= 0.0) as u8;
                        }
                        w.pose = Some(pose);
                        w.rect = Some(rect);
                        Ok(())
                    })();
                    w.stage_ns[1] = monotonic_ns() - t0;
                    match r {
                        Ok(()) => {
                            lat.record_ns(w.stage_ns[1]);
                            push(&q2_tx, &q2_rx, &free_tx, w, cfg.lossless, &dropped);
                        }
                        Err(e) => {
                            failed.push(reason(&e));
                            let _ = free_tx.send(w);
                        }
                    }
                }
                (lat, failed)
            })
        };
        drop(q2_tx);
        // ---- disparity
        let disp_stage = {
            let (q2_rx, q3_tx, q3_rx, free_tx) = (q2_rx.clone(), q3_tx.clone(), q3_rx.clone(), free_tx.clone());
            let dropped = dropped.clone();
            let engine = &mut engine;
            s.spawn(move || -> (Latency, Vec<&'static str>) {
                prewarm_thread();
                let mut lat = Latency::default();
                let mut failed = Vec::new();
                for mut w in q2_rx.iter() {
                    let t0 = monotonic_ns();
                    let Work { rect_left, rect_right, disparity, .. } = &mut *w;
                    let r = engine.compute(rect_left, rect_right, disparity);
                    w.stage_ns[2] = monotonic_ns() - t0;
                    match r {
                        Ok(()) => {
                            lat.record_ns(w.stage_ns[2]);
                            push(&q3_tx, &q3_rx, &free_tx, w, cfg.lossless, &dropped);
                        }
                        Err(_) => {
                            failed.push("disparity engine failed");
                            let _ = free_tx.send(w);
                        }
                    }
                }
                (lat, failed)
            })
        };
        drop(q3_tx);
        // ---- output: depth, cloud, sinks (this thread), and the statistics windows
        let mut depth = DepthFrame::new(out.0, out.1);
        let window_ns = (cfg.window.as_nanos().clamp(1_000_000, i64::MAX as u128)) as i64;
        let mut win = WindowCounter::new(started, window_ns);
        win.prepare(&mut stats, cfg.duration);
        loop {
            let now = monotonic_ns();
            if now >= win.end_ns {
                win.close(now, &mut stats, &frames_in, &dropped);
                continue;
            }
            let w = match q3_rx.recv_timeout(Duration::from_nanos((win.end_ns - now) as u64)) {
                Ok(w) => w,
                Err(RecvTimeoutError::Timeout) => continue,
                Err(RecvTimeoutError::Disconnected) => break,
            };
            let t0 = monotonic_ns();
            let (Some(pose), Some(rect)) = (w.pose.as_ref(), w.rect.as_ref()) else {
                let _ = free_tx.send(w);
                continue;
            };
            let valid = &w.valid;
            depth.compute(&w.disparity, |i| valid[i] != 0, &w.rect_left, &cfg.out, rect, &pose.rel_left, &cfg.depth);
            let published = Published {
                seq: w.seq,
                session_seq: w.session_seq,
                t_frame_ns: w.t_frame_ns,
                theta: &w.theta,
                pose,
                rect,
                cam: &cfg.out,
                depth: &depth,
                left_rect: &w.rect_left,
                right_rect: &w.rect_right,
                disparity: &w.disparity,
            };
            let mut ok = true;
            for sink in sinks.iter_mut() {
                if let Err(e) = sink.consume(&published) {
                    ok = false;
                    eprintln!("warning: frame {}: sink {}: {e}", w.seq, sink.name());
                    stats.fail("sink failed");
                }
            }
            let t1 = monotonic_ns();
            stats.stage_mut("output").record_ns(t1 - t0);
            if ok {
                stats.frames_published += 1;
                stats.points_total += depth.n_points as u64;
                stats.end_to_end.record_ns(t1 - w.t_frame_ns);
                win.latency.record_ns(t1 - w.t_frame_ns);
                stats.digest(&depth.depth);
            }
            let _ = free_tx.send(w);
        }
        win.close(monotonic_ns(), &mut stats, &frames_in, &dropped);
        let src_lat = src.join().map_err(|_| RuntimeError::Invalid("source thread panicked".into()))?;
        for (name, h) in [("rectify", rect_stage), ("disparity", disp_stage)] {
            let (lat, failed) = h.join().map_err(|_| RuntimeError::Invalid(format!("{name} thread panicked")))?;
            stats.stage_mut(name).merge(&lat);
            for f in failed {
                stats.fail(f);
            }
        }
        stats.stage_mut("source").merge(&src_lat);
        Ok(())
    });
    result?;
    stats.frames_in = frames_in.load(Ordering::Relaxed);
    stats.frames_dropped = dropped.load(Ordering::Relaxed);
    stats.extra.insert(
        "encoder_samples_refused".into(),
        serde_json::json!(tracks[0].stats.non_monotonic + tracks[1].stats.non_monotonic),
    );
    let elapsed = (monotonic_ns() - started) as f64 * 1e-9;
    stats.extra.insert("elapsed_s".into(), serde_json::json!(elapsed));
    source.finish(&mut stats);
    for sink in sinks.iter_mut() {
        sink.finish(&mut stats);
    }
    Ok(stats)
}

/// The statistics window being filled (see [`PipelineConfig::window`]): closing one reads the counters and the
/// resident memory; neither allocates (the list of windows is reserved up front for an hour, or for the run's
/// duration).
struct WindowCounter {
    started: i64,
    len_ns: i64,
    end_ns: i64,
    latency: Latency,
    /// Counters at the window's start: frames in, published, dropped.
    at_start: [u64; 3],
}

impl WindowCounter {
    fn new(started: i64, len_ns: i64) -> Self {
        WindowCounter { started, len_ns, end_ns: started + len_ns, latency: Latency::default(), at_start: [0; 3] }
    }

    /// Sets the run's window length and reserves its list: the run's windows, or an hour's (a longer run
    /// without a duration grows the list, doubling, about once an hour and then ever more rarely).
    fn prepare(&self, stats: &mut RunStats, duration: Option<Duration>) {
        stats.window_s = self.len_ns as f64 / 1e9;
        let n = match duration {
            Some(d) => (d.as_nanos() / self.len_ns as u128) as usize + 2,
            None => (3600_000_000_000 / self.len_ns) as usize + 2,
        };
        stats.windows.reserve(n.min(1 << 16));
    }

    fn close(&mut self, now: i64, stats: &mut RunStats, frames_in: &AtomicU64, dropped: &AtomicU64) {
        let counts = [frames_in.load(Ordering::Relaxed), stats.frames_published, dropped.load(Ordering::Relaxed)];
        let l = &self.latency;
        stats.windows.push(Window {
            t_s: (now - self.started) as f64 * 1e-9,
            frames_in: counts[0] - self.at_start[0],
            frames_published: counts[1] - self.at_start[1],
            frames_dropped: counts[2] - self.at_start[2],
            p50_ms: l.ms(0.5),
            p99_ms: l.ms(0.99),
            max_ms: l.max_ms(),
            rss_bytes: rss_bytes().unwrap_or(0),
        });
        self.at_start = counts;
        self.latency.reset();
        while self.end_ns <= now {
            self.end_ns += self.len_ns;
        }
    }
}

/// Failure reason of a frame, for the counters (static: counting must not allocate).
fn reason(e: &RuntimeError) -> &'static str {
    match e {
        RuntimeError::OutOfSpan { .. } => "encoders do not cover the frame time",
        RuntimeError::Gap { .. } => "gap in the encoder stream",
        RuntimeError::NonMonotonic { .. } => "non-monotonic timestamps",
        _ => "kinematics or rectification failed",
    }
}
