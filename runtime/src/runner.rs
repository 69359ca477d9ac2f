//! The generic runner: a source, lanes of [`Stage`]s and sinks, built from a description and run on
//! threads joined by bounded crossbeam channels, data flowing one way.
//!
//! ```text
//! source ──q──> lane 1 (stages) ──q──> ... ──q──> output lane (stages, then the sinks)
//!    ^                                                        │
//!    └──────────── free list of pooled work buffers ──────────┘
//! ```
//! Every frame travels in one pooled [`Work`] item allocated at start-up and returned to the free list at
//! the end, so steady state does not allocate. Under overload a full queue drops its **oldest** item
//! (counted) to make room: latency stays bounded by the queue depths instead of growing. In lossless mode
//! (offline processing, reproducible replays) queues block instead. Each lane is one thread and one latency
//! histogram; the sinks run on the output lane. Nothing here knows which stages or sinks a graph has.
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use crossbeam_channel::{bounded, Receiver, RecvTimeoutError, Select, Sender, TrySendError};

use abvs_runtime_core::cpu::RunCpu;
use abvs_runtime_core::error::{Result, RuntimeError};
use abvs_runtime_core::messages::{monotonic_ns, DepthFrame, RectifiedCamera, Work};
use abvs_runtime_core::sink::Sink;
use abvs_runtime_core::source::PairSource;
use abvs_runtime_core::stage::{Stage, StageContext};
use abvs_runtime_core::stats::{rss_bytes, Latency, RunStats, Window, MAX_WINDOWS};

/// One thread of the graph: stages run in order on each frame.
pub struct Lane {
    /// The lane's name in the statistics (its latency histogram).
    pub name: &'static str,
    /// The stages, in the order they run on each frame.
    pub stages: Vec<Box<dyn Stage>>,
}

/// A source, lanes of stages (the last is the output lane, where the sinks run) and sinks.
pub struct Graph<S> {
    /// Where the frames come from.
    pub source: S,
    /// The rectified output the stages after rectification work at (sizes the pooled buffers).
    pub out: RectifiedCamera,
    /// The lanes, in data-flow order; the last is the output lane.
    pub lanes: Vec<Lane>,
    /// The sinks, in the order they run on the output lane.
    pub sinks: Vec<Box<dyn Sink>>,
}

impl<S: PairSource> Graph<S> {
    /// Builds the graph a description names: lanes separated by `;`, each `name = stage, stage, ...`, the
    /// last the output lane, e.g. `"rectify = align, kinematics, rectify; disparity = disparity; output =
    /// depth"`. Every stage given is named exactly once and every name is given.
    pub fn from_description(
        source: S,
        out: RectifiedCamera,
        description: &'static str,
        stages: Vec<Box<dyn Stage>>,
        sinks: Vec<Box<dyn Sink>>,
    ) -> Result<Self> {
        let bad = |msg: String| RuntimeError::Invalid(format!("stage graph `{description}`: {msg}"));
        let mut pool: Vec<Option<Box<dyn Stage>>> = stages.into_iter().map(Some).collect();
        let mut lanes = Vec::new();
        for lane in description.split(';').map(str::trim).filter(|l| !l.is_empty()) {
            let (name, list) = lane.split_once('=').ok_or_else(|| bad(format!("lane `{lane}` has no `=`")))?;
            let mut stages = Vec::new();
            for stage in list.split(',').map(str::trim).filter(|s| !s.is_empty()) {
                let i = pool
                    .iter()
                    .position(|s| s.as_ref().is_some_and(|s| s.name() == stage))
                    .ok_or_else(|| bad(format!("no stage `{stage}` given (or it is named twice)")))?;
                stages.push(pool[i].take().expect("found above"));
            }
            lanes.push(Lane { name: name.trim(), stages });
        }
        if let Some(s) = pool.iter().flatten().next() {
            return Err(bad(format!("stage `{}` is given but not placed", s.name())));
        }
        let g = Graph { source, out, lanes, sinks };
        g.check()?;
        Ok(g)
    }

    /// Adds a sink (it runs on the output lane, after the sinks already there).
    pub fn add_sink(&mut self, sink: Box<dyn Sink>) {
        self.sinks.push(sink);
    }

    /// Adds a side stage at the end of the lane `lane`.
    pub fn add_stage(&mut self, lane: &str, stage: Box<dyn Stage>) -> Result<()> {
        let l = self
            .lanes
            .iter_mut()
            .find(|l| l.name == lane)
            .ok_or_else(|| RuntimeError::Invalid(format!("stage graph: no lane `{lane}` for {}", stage.name())))?;
        l.stages.push(stage);
        self.check()
    }

    /// The lanes' names in the statistics, the source's first.
    pub fn stage_names(&self) -> Vec<&'static str> {
        std::iter::once("source").chain(self.lanes.iter().map(|l| l.name)).collect()
    }

    fn check(&self) -> Result<()> {
        let bad = |msg: String| Err(RuntimeError::Invalid(format!("stage graph: {msg}")));
        if self.lanes.is_empty() {
            return bad("no lanes".into());
        }
        let n = self.lanes.len();
        for (i, l) in self.lanes.iter().enumerate() {
            if let Some(s) = l.stages.iter().find(|s| s.needs_output_lane() && i + 1 != n) {
                return bad(format!(
                    "stage `{}` writes depth and must be on the output lane, not `{}`",
                    s.name(),
                    l.name
                ));
            }
            if self.lanes[..i].iter().any(|o| o.name == l.name) || l.name == "source" {
                return bad(format!("lane name `{}` used twice", l.name));
            }
        }
        Ok(())
    }
}

/// A run's counters, readable from any thread while it runs ([`RunConfig::progress`]).
#[derive(Debug, Default)]
pub struct Progress {
    /// Frames taken from the source.
    pub frames_in: AtomicU64,
    /// Frames that reached the sinks.
    pub frames_published: AtomicU64,
    /// Frames dropped under overload (oldest first) at a queue.
    pub frames_dropped: AtomicU64,
}

/// The counts of a [`Progress`] at one moment.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counts {
    /// Frames taken from the source.
    pub frames_in: u64,
    /// Frames that reached the sinks.
    pub frames_published: u64,
    /// Frames dropped under overload.
    pub frames_dropped: u64,
}

impl Progress {
    /// The counts now.
    pub fn counts(&self) -> Counts {
        Counts {
            frames_in: self.frames_in.load(Ordering::Relaxed),
            frames_published: self.frames_published.load(Ordering::Relaxed),
            frames_dropped: self.frames_dropped.load(Ordering::Relaxed),
        }
    }
}

/// How the runner moves frames (the graph says what is done to them).
#[derive(Debug, Clone)]
pub struct RunConfig {
    /// Capacity of each inter-lane queue.
    pub queue: usize,
    /// Block instead of dropping: every frame is processed (offline, reproducible).
    pub lossless: bool,
    /// Release replayed frames at their recorded times (as a live camera would).
    pub paced: bool,
    /// Number of frames (looping the session); `None` plays it once.
    pub frames: Option<u64>,
    /// Stop taking frames from the source this long after the start (the frames in flight finish).
    pub duration: Option<Duration>,
    /// Length of a statistics window ([`RunStats::windows`]).
    pub window: Duration,
    /// Stop taking frames once this is set (Ctrl-C, SIGTERM): the frames in flight finish and the run
    /// returns its statistics as at the end of a replay.
    pub stop: Option<Arc<AtomicBool>>,
    /// Counters to update as the run goes, for another thread to read (the run keeps its own otherwise).
    pub progress: Option<Arc<Progress>>,
}

type Queue = (Sender<Box<Work>>, Receiver<Box<Work>>);

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

/// Nice level of the pipeline's threads off its bottleneck: low enough that the engine's lane wins its
/// core when both are ready, high enough that they keep up (they need about a third of a core).
pub const OFF_CRITICAL_NICE: i32 = 5;

/// Lowers the calling thread's priority to [`OFF_CRITICAL_NICE`] (Linux: nice applies per thread). Raising
/// a nice level needs no privilege; a failure leaves the thread as it was, which only costs frame rate.
fn step_back_priority() {
    #[cfg(target_os = "linux")]
    // SAFETY: a plain system call on the calling thread (who = 0).
    unsafe {
        libc::setpriority(libc::PRIO_PROCESS, 0, OFF_CRITICAL_NICE);
    }
}

/// crossbeam allocates once, lazily, the first time a thread blocks on any channel (its thread-local wait
/// context). Left to chance that can happen hundreds of frames into a run (the first time a stage finds its
/// queue empty), so every lane's thread takes that allocation at start-up instead.
fn prewarm_thread() {
    let (_tx, rx) = bounded::<()>(0);
    let _ = rx.recv_timeout(Duration::from_micros(1));
}

/// The other lazy crossbeam allocation: the list of threads waiting on one side of a channel is allocated
/// (capacity 4, kept afterwards) the first time a thread waits there. A `Select` with a zero timeout
/// registers a waiter on every operation that is not ready and then gives up without blocking, so it
/// allocates every list at once: receivers on the empty channels, then senders on the full work queues.
fn prewarm_waiter_lists(free: &Queue, queues: &[Queue]) {
    let mut spare: Vec<Box<Work>> = free.1.try_iter().collect();
    let n = spare.len();
    let mut sel = Select::new();
    sel.recv(&free.1);
    for q in queues {
        sel.recv(&q.1);
    }
    // all channels are empty: nothing can be selected, the call only registers and times out
    assert!(sel.select_timeout(Duration::ZERO).is_err(), "pre-warm: an empty queue was ready");
    let mut sel = Select::new();
    for q in queues {
        while !q.0.is_full() {
            let Some(w) = spare.pop() else { break };
            let _ = q.0.try_send(w);
        }
        sel.send(&q.0);
    }
    if queues.iter().all(|q| q.0.is_full()) {
        assert!(sel.select_timeout(Duration::ZERO).is_err(), "pre-warm: a full queue was ready");
    }
    for q in queues {
        spare.extend(q.1.try_iter());
    }
    assert_eq!(spare.len(), n, "pre-warm lost a buffer");
    for w in spare {
        free.0.send(w).expect("free list has room");
    }
}

/// A lane's thread: named `abvs-{lane}` (what `top -H` and `perf` show). Panics where the system cannot
/// make a thread, as `Scope::spawn` does: the lanes already running would otherwise wait on it for ever.
fn lane_thread<'scope, 'env, T: Send + 'scope>(
    s: &'scope std::thread::Scope<'scope, 'env>,
    lane: &str,
    f: impl FnOnce() -> T + Send + 'scope,
) -> std::thread::ScopedJoinHandle<'scope, T> {
    std::thread::Builder::new().name(format!("abvs-{lane}")).spawn_scoped(s, f).expect("spawning a lane's thread")
}

/// A lane thread's own CPU time, from its start.
struct LaneCpu {
    tid: i32,
    ns: i64,
}

impl LaneCpu {
    fn start() -> LaneCpu {
        LaneCpu { tid: abvs_runtime_core::cpu::thread_id(), ns: abvs_runtime_core::cpu::thread_cpu_ns() }
    }
    fn stop(self) -> LaneCpu {
        LaneCpu { tid: self.tid, ns: abvs_runtime_core::cpu::thread_cpu_ns() - self.ns }
    }
}

/// Runs a lane's stages on one frame; the first failure names its counter.
fn process(stages: &mut [Box<dyn Stage>], w: &mut Work) -> std::result::Result<(), &'static str> {
    process_or_shed(stages, w, false).map(|_| ())
}

/// [`process`], where a stage may let the frame pass when its lane is `behind` ([`Stage::shed`]); returns
/// whether every stage did its work.
fn process_or_shed(
    stages: &mut [Box<dyn Stage>],
    w: &mut Work,
    behind: bool,
) -> std::result::Result<bool, &'static str> {
    let mut whole = true;
    for s in stages.iter_mut() {
        if behind && s.shed(w) {
            whole = false;
            continue;
        }
        if let Err(e) = s.process(w) {
            return Err(s.failure(&e));
        }
    }
    Ok(whole)
}

/// Runs a graph to the end of its source (or its duration, or the stop flag) and returns its statistics.
pub fn run<S: PairSource>(graph: Graph<S>, cfg: &RunConfig) -> Result<RunStats> {
    graph.check()?;
    let names = graph.stage_names();
    let Graph { mut source, out: cam, mut lanes, mut sinks } = graph;
    let (rw, rh) = source.size();
    let out = (cam.width, cam.height);
    let cfg = cfg.clone();

    let q = cfg.queue.max(1);
    let n = lanes.len();
    // Enough buffers that the source always finds a free one when it takes a frame: the n queues hold at
    // most n q, every lane but the output at most 2 (the frame it pushes and, while a full queue drops its
    // oldest, that one on its way back to the free list), the output 1, the source none at that moment:
    // n q + 2 (n - 1) + 1 in use, so one is always free and under overload only the oldest queued frames
    // are dropped. (Three lanes: 3 q + 6.)
    let pool = n * q + 2 * (n - 1) + 2;
    let free: Queue = bounded::<Box<Work>>(pool);
    for _ in 0..pool {
        let mut w = Work::new((rw, rh), out);
        for s in lanes.iter().flat_map(|l| l.stages.iter()) {
            s.prepare_work(&mut w);
        }
        free.0.send(w).expect("free list has room");
    }
    // queue i feeds lane i (queue 0 from the source)
    let queues: Vec<Queue> = (0..n).map(|_| bounded::<Box<Work>>(q)).collect();
    // (the free list's senders never wait: it has room for every buffer)
    prewarm_waiter_lists(&free, &queues);
    let progress = cfg.progress.clone().unwrap_or_default();
    let mut stats = RunStats::new(&names);
    let started = monotonic_ns();
    // the board's command side first: a live source's start hands its encoder stream away
    let mut board = source.board();
    let mut encoders = Some(source.start(started + 5_000_000));
    let mut ctx = StageContext { raw: (rw, rh), out: cam, encoders: &mut encoders, board: &mut board };
    for s in lanes.iter_mut().flat_map(|l| l.stages.iter_mut()) {
        s.start(&mut ctx)?;
    }
    // With a lane that bounds the frame rate (the disparity engine's), the source and the other lanes before
    // the output step back a little (nice +OFF_CRITICAL_NICE): on a 2-core robot computer they fill the
    // engine's gaps instead of taking its core in the middle of a frame. Measured on the fixture (2 cores,
    // paced): see runtime/BENCHMARKS.md "Real time".
    let step_back: Vec<bool> = {
        let any = lanes.iter().any(|l| l.stages.iter().any(|s| s.bottleneck()));
        lanes.iter().map(|l| any && !l.stages.iter().any(|s| s.bottleneck())).collect()
    };
    let source_steps_back = step_back.iter().any(|b| *b);
    // Each sender moves to its one producer, so a queue disconnects when that producer ends.
    let mut senders: Vec<Option<Sender<Box<Work>>>> = queues.iter().map(|q| Some(q.0.clone())).collect();
    let receivers: Vec<Receiver<Box<Work>>> = queues.iter().map(|q| q.1.clone()).collect();
    drop(queues);
    let (free_tx, free_rx) = free;
    let (output, middle) = lanes.split_last_mut().expect("checked: at least one lane");

    let cpu_before = abvs_runtime_core::cpu::threads();
    let process_cpu0 = abvs_runtime_core::cpu::process_cpu_ns();
    let result = std::thread::scope(|s| -> Result<()> {
        // ---- source
        let src = {
            let (free_rx, free_tx) = (free_rx.clone(), free_tx.clone());
            let (q_tx, q_rx) = (senders[0].take().expect("one producer"), receivers[0].clone());
            let progress = progress.clone();
            let stop = cfg.stop.clone();
            let source = &mut source;
            lane_thread(s, "source", move || -> (Latency, LaneCpu) {
                let cpu = LaneCpu::start();
                prewarm_thread();
                if source_steps_back {
                    step_back_priority();
                }
                let mut lat = Latency::default();
                let end_ns = cfg.duration.map(|d| started.saturating_add(d.as_nanos().min(i64::MAX as u128) as i64));
                loop {
                    if end_ns.is_some_and(|end| monotonic_ns() >= end)
                        || stop.as_ref().is_some_and(|s| s.load(Ordering::Relaxed))
                    {
                        break;
                    }
                    let Some(f) = source.next_frame(cfg.frames) else { break };
                    progress.frames_in.fetch_add(1, Ordering::Relaxed);
                    // a frame exists once its last row's exposure ended (rolling shutter: readout after the first)
                    let ready = f.t_start_ns + f.readout_ns + f.exposure_ns;
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
                            progress.frames_dropped.fetch_add(1, Ordering::Relaxed);
                            continue;
                        }
                    };
                    w.fill(&f);
                    lat.record_ns(monotonic_ns() - t0);
                    push(&q_tx, &q_rx, &free_tx, w, cfg.lossless, &progress.frames_dropped);
                }
                drop(q_tx);
                (lat, cpu.stop())
            })
        };
        // ---- the lanes before the output, one thread each
        let mut handles = Vec::with_capacity(middle.len());
        for (i, lane) in middle.iter_mut().enumerate() {
            let (rx, free_tx) = (receivers[i].clone(), free_tx.clone());
            let (q_tx, q_rx) = (senders[i + 1].take().expect("one producer"), receivers[i + 1].clone());
            let progress = progress.clone();
            let name = lane.name;
            let steps_back = step_back[i];
            let h = lane_thread(s, name, move || -> (Latency, Vec<&'static str>, LaneCpu) {
                let cpu = LaneCpu::start();
                prewarm_thread();
                if steps_back {
                    step_back_priority();
                }
                let mut lat = Latency::default();
                let mut failed = Vec::new();
                for mut w in rx.iter() {
                    let t0 = monotonic_ns();
                    // behind: a newer frame already waits (a lossless run never sheds)
                    let behind = !cfg.lossless && !rx.is_empty();
                    match process_or_shed(&mut lane.stages, &mut w, behind) {
                        Ok(whole) => {
                            // the lane's latency is its work's: a shed frame's pass-through is not
                            if whole {
                                lat.record_ns(monotonic_ns() - t0);
                            }
                            push(&q_tx, &q_rx, &free_tx, w, cfg.lossless, &progress.frames_dropped);
                        }
                        Err(reason) => {
                            failed.push(reason);
                            let _ = free_tx.send(w);
                        }
                    }
                }
                (lat, failed, cpu.stop())
            });
            handles.push((name, h));
        }
        // ---- the output lane: its stages, the sinks (this thread), and the statistics windows
        let rx = receivers[n - 1].clone();
        // the one depth buffer, lent to the frame being published (see `Work::depth`)
        let mut depth = DepthFrame::new(out.0, out.1);
        let window_ns = (cfg.window.as_nanos().clamp(1_000_000, i64::MAX as u128)) as i64;
        let mut win = WindowCounter::new(started, window_ns);
        win.prepare(&mut stats);
        let out_cpu = LaneCpu::start();
        loop {
            let now = monotonic_ns();
            if now >= win.end_ns {
                win.close(now, &mut stats, &progress);
                continue;
            }
            let mut w = match rx.recv_timeout(Duration::from_nanos((win.end_ns - now) as u64)) {
                Ok(w) => w,
                Err(RecvTimeoutError::Timeout) => continue,
                Err(RecvTimeoutError::Disconnected) => break,
            };
            let t0 = monotonic_ns();
            std::mem::swap(&mut w.depth, &mut depth);
            // a sink that sends the depth map lends it its message's buffer (see `Sink::lend_depth`)
            for sink in sinks.iter_mut() {
                match sink.lend_depth(&mut w.depth) {
                    Ok(true) => break,
                    Ok(false) => {}
                    Err(e) => sink_failed(&mut stats, sink.name(), w.seq, &e),
                }
            }
            if let Err(reason) = process(&mut output.stages, &mut w) {
                stats.fail(reason);
            } else if let Some(published) = w.published(&cam) {
                for sink in sinks.iter_mut() {
                    if let Err(e) = sink.consume(&published) {
                        // that sink's failure, not the frame's: the other sinks took it
                        sink_failed(&mut stats, sink.name(), w.seq, &e);
                    }
                }
                let t1 = monotonic_ns();
                stats.stage_mut(output.name).record_ns(t1 - t0);
                stats.frames_published += 1;
                progress.frames_published.store(stats.frames_published, Ordering::Relaxed);
                stats.points_total += w.depth.n_points as u64;
                // from the moment the frame exists (its last row's exposure ended): the runtime's own latency;
                // the depth describes the frame's instant, readout / 2 + exposure / 2 before that
                let m = &w.motion;
                let ready = m.t_start_ns[0] + m.readout_ns + m.exposure_ns;
                stats.end_to_end.record_ns(t1 - ready);
                win.latency.record_ns(t1 - ready);
                if cfg.lossless {
                    stats.digest(&w.depth.depth);
                }
            }
            for sink in sinks.iter_mut() {
                if let Err(e) = sink.frame_done(&mut w.depth) {
                    sink_failed(&mut stats, sink.name(), w.seq, &e);
                }
            }
            std::mem::swap(&mut w.depth, &mut depth);
            let _ = free_tx.send(w);
        }
        win.close(monotonic_ns(), &mut stats, &progress);
        let out_cpu = out_cpu.stop();
        let (src_lat, src_cpu) = src.join().map_err(|_| RuntimeError::Panicked("source thread".into()))?;
        let mut lane_cpu = vec![("source", src_cpu)];
        for (name, h) in handles {
            let (lat, failed, cpu) = h.join().map_err(|_| RuntimeError::Panicked(format!("{name} thread")))?;
            stats.stage_mut(name).merge(&lat);
            for f in failed {
                stats.fail(f);
            }
            lane_cpu.push((name, cpu));
        }
        lane_cpu.push((output.name, out_cpu));
        stats.stage_mut("source").merge(&src_lat);
        let process_name = std::fs::read_to_string("/proc/self/comm").unwrap_or_default();
        let tids: Vec<i32> = lane_cpu.iter().map(|(_, c)| c.tid).collect();
        let (others, idle_ns) =
            RunCpu::others_between(&cpu_before, &abvs_runtime_core::cpu::threads(), &tids, process_name.trim());
        stats.cpu = Some(RunCpu {
            lanes: lane_cpu.iter().map(|(n, c)| (*n, c.ns)).collect(),
            process_ns: abvs_runtime_core::cpu::process_cpu_ns() - process_cpu0,
            others,
            idle_ns,
        });
        Ok(())
    });
    result?;
    stats.frames_in = progress.frames_in.load(Ordering::Relaxed);
    stats.frames_dropped = progress.frames_dropped.load(Ordering::Relaxed);
    let elapsed = (monotonic_ns() - started) as f64 * 1e-9;
    stats.extra.insert("elapsed_s".into(), serde_json::json!(elapsed));
    source.finish(&mut stats);
    for s in lanes.iter_mut().flat_map(|l| l.stages.iter_mut()) {
        s.finish(&mut stats);
    }
    for sink in sinks.iter_mut() {
        sink.finish(&mut stats);
    }
    Ok(stats)
}

/// Counts a sink's failure on frame `seq` (the frame still went to the other sinks); logs the first.
fn sink_failed(stats: &mut RunStats, sink: &str, seq: u64, e: &RuntimeError) {
    let n = stats.sink_failures.entry(sink.to_string()).or_default();
    *n += 1;
    if *n == 1 {
        log::warn!("frame {seq}: sink {sink}: {e} (further failures of this sink are counted)");
    }
}

/// The statistics window being filled (see [`RunConfig::window`]): closing one reads the counters and the
/// resident memory; neither allocates (the list of windows is reserved and written up front, [`MAX_WINDOWS`]
/// long: at that many, neighbours merge in pairs and the window doubles).
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

    /// Sets the run's window length and reserves its list, [`MAX_WINDOWS`] long, each page written once: the
    /// list's memory is resident from the start, whatever the run's length.
    fn prepare(&self, stats: &mut RunStats) {
        stats.window_s = self.len_ns as f64 / 1e9;
        let empty = Window {
            t_s: 0.0,
            frames_in: 0,
            frames_published: 0,
            frames_dropped: 0,
            p50_ms: 0.0,
            p99_ms: 0.0,
            max_ms: 0.0,
            rss_bytes: 0,
        };
        stats.windows.clear();
        stats.windows.reserve_exact(MAX_WINDOWS);
        std::hint::black_box(&mut stats.windows);
        stats.windows.resize(MAX_WINDOWS, empty);
        std::hint::black_box(&mut stats.windows);
        stats.windows.clear();
    }

    fn close(&mut self, now: i64, stats: &mut RunStats, progress: &Progress) {
        let counts = [
            progress.frames_in.load(Ordering::Relaxed),
            stats.frames_published,
            progress.frames_dropped.load(Ordering::Relaxed),
        ];
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
        if stats.windows.len() == MAX_WINDOWS {
            // full: neighbours merge, the window doubles (the list never grows)
            let w = &mut stats.windows;
            for i in 0..MAX_WINDOWS / 2 {
                w[i] = w[2 * i].merged(&w[2 * i + 1]);
            }
            w.truncate(MAX_WINDOWS / 2);
            self.len_ns = self.len_ns.saturating_mul(2);
            stats.window_s = self.len_ns as f64 / 1e9;
        }
        self.at_start = counts;
        self.latency.reset();
        while self.end_ns <= now {
            self.end_ns += self.len_ns;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_window_list_stays_within_its_reservation_for_a_run_of_any_length() {
        let mut stats = RunStats::new(&["source"]);
        let len_ns = 10_000_000; // 10 ms windows: a day of them would be 8.6 million
        let mut win = WindowCounter::new(0, len_ns);
        win.prepare(&mut stats);
        let (cap, ptr) = (stats.windows.capacity(), stats.windows.as_ptr());
        assert!(cap >= MAX_WINDOWS);
        let progress = Progress::default();
        let n = 3 * MAX_WINDOWS + 5;
        // as the output lane does: a frame every 5 ms, the window closed when its end has passed, and at the end
        for k in 1..=2 * n as i64 {
            progress.frames_in.fetch_add(1, Ordering::Relaxed);
            stats.frames_published += 1;
            win.latency.record_ns(5_000_000);
            let now = k * len_ns / 2;
            if now >= win.end_ns && k < 2 * n as i64 {
                win.close(now, &mut stats, &progress);
            }
        }
        win.close(n as i64 * len_ns, &mut stats, &progress);
        // the same buffer throughout (no reallocation), at most MAX_WINDOWS windows, every frame counted
        assert_eq!((stats.windows.capacity(), stats.windows.as_ptr()), (cap, ptr));
        assert!(stats.windows.len() < MAX_WINDOWS && stats.windows.len() > MAX_WINDOWS / 4, "{}", stats.windows.len());
        let total: u64 = stats.windows.iter().map(|w| w.frames_in).sum();
        assert_eq!(total, 2 * n as u64);
        // the windows doubled twice; the last one ends at the last close
        assert!((stats.window_s - 0.04).abs() < 1e-12, "{}", stats.window_s);
        assert!((stats.windows.last().unwrap().t_s - n as f64 * 0.01).abs() < 1e-9);
        assert!(stats.windows.iter().all(|w| (w.p50_ms - 5.0).abs() < 0.01 && (w.p99_ms - 5.0).abs() < 0.01));
    }
}
