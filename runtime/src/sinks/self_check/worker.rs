//! The sink and its worker thread: pooled jobs, idle-priority checking, the summary at the end.
use super::log_record::{match_log_path, FrameRecord, LogRecord, LogWriter, MatchRecord};
use super::*;
use abvs_runtime_core::params::SelfCheckConfig;

/// One rectified pair handed to the worker (pooled: allocated at start-up).
pub struct Job {
    /// The frame's pipeline sequence number.
    pub seq: u64,
    /// The frame's instant (CLOCK_MONOTONIC ns).
    pub t_frame_ns: i64,
    /// Both eyes' link angles (deg).
    pub theta: [[f64; 3]; 2],
    /// rect_from_left R_rel,l^T.
    pub rot: Matrix3<f64>,
    /// The rectified camera of the pair.
    pub cam: RectifiedCamera,
    /// Largest disparity searched (px).
    pub max_disp: f32,
    /// The rectifying rotations and the baseline.
    pub rect: Rectification,
    /// Per-row rotations of each eye (`FrameMotion::band_rot`; empty: corrected as a whole).
    pub band_rot: [Vec<Matrix3<f64>>; 2],
    /// Each camera's angular velocity in its own frame (rad/s).
    pub omega_rad_s: [Vector3<f64>; 2],
    /// Each camera's angular speed (deg/s).
    pub speed_deg_s: [f64; 2],
    /// Each camera's mean angular velocity just before and after the instant (`FrameMotion::omega_wide_rad_s`).
    pub omega_wide_rad_s: [[Vector3<f64>; 2]; 2],
    /// Each camera's optical-centre velocity in its own frame (m/s).
    pub vel_m_s: [Vector3<f64>; 2],
    /// Readout and exposure the runtime assumed (ms), and the row the stamps fix (fraction).
    pub readout_ms: f64,
    /// Exposure (ms).
    pub exposure_ms: f64,
    /// `SourcePair::readout_anchor`.
    pub readout_anchor: f64,
    /// Rectified left image.
    pub left: Vec<u8>,
    /// Rectified right image.
    pub right: Vec<u8>,
}

/// The sink: copies every `every`-th rectified pair into a pooled job for the worker thread.
pub struct SelfCheckSink {
    cfg: SelfCheckConfig,
    tx: Option<Sender<Box<Job>>>,
    free: Receiver<Box<Job>>,
    worker: Option<JoinHandle<Summary>>,
    skipped: u64,
}

impl SelfCheckSink {
    /// Starts the worker for rectified pairs of `cam`'s size; creates the log file (if any) now.
    pub fn new(cfg: SelfCheckConfig, cam: &RectifiedCamera) -> Result<SelfCheckSink> {
        SelfCheckSink::with_timing(cfg, cam, None)
    }

    /// As [`SelfCheckSink::new`]; with `timing`, the log also gets every match's timing evidence
    /// (`<log>.matches.csv`, [`match_log_path`]) for `abvs calib self-check` to estimate the eyes' timing.
    pub fn with_timing(
        cfg: SelfCheckConfig,
        cam: &RectifiedCamera,
        timing: Option<TimingContext>,
    ) -> Result<SelfCheckSink> {
        type Writer = LogWriter<std::io::BufWriter<std::fs::File>>;
        fn create<R: LogRecord>(p: &PathBuf) -> Result<(Writer, PathBuf)> {
            let io = |e: std::io::Error| RuntimeError::File { path: p.clone(), line: None, msg: e.to_string() };
            let w = LogWriter::new::<R>(std::io::BufWriter::new(std::fs::File::create(p).map_err(io)?)).map_err(io)?;
            Ok((w, p.clone()))
        }
        let mut log = cfg.log.as_ref().map(create::<FrameRecord>).transpose()?;
        let mut match_log = match (&cfg.log, &timing) {
            (Some(p), Some(_)) => Some(create::<MatchRecord>(&match_log_path(p))?),
            _ => None,
        };
        let mut matcher = Matcher::new(cfg.features, cfg.band_px)?;
        let n = (cam.width * cam.height) as usize;
        const POOL: usize = 2;
        let (free_tx, free_rx) = bounded::<Box<Job>>(POOL);
        let (tx, rx) = bounded::<Box<Job>>(POOL);
        for _ in 0..POOL {
            free_tx
                .send(Box::new(Job {
                    seq: 0,
                    t_frame_ns: 0,
                    theta: [[0.0; 3]; 2],
                    rot: Matrix3::identity(),
                    cam: *cam,
                    max_disp: 0.0,
                    rect: Rectification {
                        rect_from_left: Matrix3::identity(),
                        rect_from_right: Matrix3::identity(),
                        baseline_m: 0.0,
                    },
                    band_rot: [
                        Vec::with_capacity(abvs_runtime_core::messages::MAX_ROW_BANDS + 1),
                        Vec::with_capacity(abvs_runtime_core::messages::MAX_ROW_BANDS + 1),
                    ],
                    omega_rad_s: [Vector3::zeros(); 2],
                    speed_deg_s: [0.0; 2],
                    omega_wide_rad_s: [[Vector3::zeros(); 2]; 2],
                    vel_m_s: [Vector3::zeros(); 2],
                    readout_ms: 0.0,
                    exposure_ms: 0.0,
                    readout_anchor: 0.0,
                    left: vec![0; n],
                    right: vec![0; n],
                }))
                .expect("pool has room");
        }
        let wcfg = cfg.clone();
        let worker = std::thread::Builder::new()
            .name("self-check".into())
            .spawn(move || {
                if wcfg.background {
                    background_priority();
                }
                let mut sum = Summary::default();
                let mut matches = Vec::new();
                for job in rx.iter() {
                    let (t0, c0) = (std::time::Instant::now(), thread_cpu_ns());
                    let r = check_frame(&mut matcher, &job, &mut matches);
                    sum.check_time.record_ns(t0.elapsed().as_nanos() as i64);
                    sum.check_cpu.record_ns(thread_cpu_ns() - c0);
                    match r {
                        Ok(c) => {
                            sum.add(&c, &matches, &wcfg);
                            if let Some((w, p)) = &mut log {
                                if let Err(e) = w.write(&frame_record(&c, &job, timing.as_ref(), wcfg.run_id)) {
                                    log::warn!("self-check log {}: {e}", p.display());
                                    log = None;
                                }
                            }
                            if let (Some((w, p)), Some(ctx)) = (&mut match_log, &timing) {
                                let r = write_matches(w, &job, ctx, &matches, wcfg.run_id);
                                if let Err(e) = r {
                                    log::warn!("self-check log {}: {e}", p.display());
                                    match_log = None;
                                }
                            }
                        }
                        Err(e) => {
                            sum.failed += 1;
                            log::warn!("self-check, frame {}: {e}", job.seq);
                        }
                    }
                    let _ = free_tx.send(job);
                }
                for (mut w, p) in log.into_iter().chain(match_log) {
                    if let Err(e) = w.flush() {
                        log::warn!("self-check log {}: {e}", p.display());
                    }
                }
                sum
            })
            .map_err(|source| RuntimeError::Thread { what: "self-check: starting its thread".into(), source })?;
        Ok(SelfCheckSink { cfg, tx: Some(tx), free: free_rx, worker: Some(worker), skipped: 0 })
    }
}

/// Every match's timing evidence, one line each.
fn write_matches(
    w: &mut LogWriter<impl Write>,
    job: &Job,
    ctx: &TimingContext,
    matches: &[Match],
    run_id: u64,
) -> std::io::Result<()> {
    for m in matches {
        if let Some(t) = match_timing(m, job, ctx) {
            w.write(&match_record(job.seq, m, &t, &design_row(m, &job.cam, &job.rot), run_id))?;
        }
    }
    Ok(())
}

/// CPU time of the calling thread (ns).
pub(super) fn thread_cpu_ns() -> i64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: a valid clock id and a valid out pointer.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    ts.tv_sec * 1_000_000_000 + ts.tv_nsec
}

/// This thread runs only on idle CPU time: SCHED_IDLE, or nice 19 where that is refused (Linux applies
/// both per thread).
pub(super) fn background_priority() {
    // SAFETY: plain system calls on the calling thread with a valid, initialised parameter.
    unsafe {
        let param = libc::sched_param { sched_priority: 0 };
        if libc::sched_setscheduler(0, libc::SCHED_IDLE, &param) != 0 {
            libc::setpriority(libc::PRIO_PROCESS, libc::gettid() as libc::id_t, 19);
        }
    }
}

impl Sink for SelfCheckSink {
    fn name(&self) -> &'static str {
        "self-check"
    }

    fn consume(&mut self, out: &Published) -> Result<()> {
        // a motion-gated frame is too blurred for sub-pixel matches: it would measure the blur, not the
        // calibration
        if out.seq % self.cfg.every.max(1) != 0 || out.motion.gated {
            return Ok(());
        }
        let Some(tx) = &self.tx else { return Ok(()) };
        let job = if self.cfg.blocking { self.free.recv().ok() } else { self.free.try_recv().ok() };
        let Some(mut job) = job else {
            self.skipped += 1;
            return Ok(());
        };
        if job.left.len() != out.left_rect.len() || job.cam != *out.cam {
            return Err(RuntimeError::Invalid("self-check: the rectified size changed".into()));
        }
        job.seq = out.seq;
        job.t_frame_ns = out.t_frame_ns;
        job.theta = *out.theta;
        job.rot = frame_rotation(out);
        job.max_disp = (out.cam.f * out.rect.baseline_m / self.cfg.min_depth_m) as f32 + 2.0;
        job.rect = *out.rect;
        let m = out.motion;
        for eye in 0..2 {
            job.band_rot[eye].clear();
            job.band_rot[eye].extend_from_slice(&m.band_rot[eye]);
        }
        (job.omega_rad_s, job.speed_deg_s, job.omega_wide_rad_s) = (m.omega_rad_s, m.speed_deg_s, m.omega_wide_rad_s);
        job.vel_m_s = m.vel_m_s;
        job.readout_ms = m.readout_ns as f64 * 1e-6;
        job.exposure_ms = m.exposure_ns as f64 * 1e-6;
        job.readout_anchor = m.readout_anchor;
        job.left.copy_from_slice(out.left_rect);
        job.right.copy_from_slice(out.right_rect);
        if tx.send(job).is_err() {
            self.skipped += 1;
        }
        Ok(())
    }

    fn finish(&mut self, stats: &mut RunStats) {
        self.tx = None;
        let Some(h) = self.worker.take() else { return };
        match h.join() {
            Ok(mut sum) => {
                sum.skipped = self.skipped;
                stats.extra.insert("self_check".into(), sum.json());
            }
            Err(_) => log::warn!("the self-check thread panicked"),
        }
    }
}

impl Drop for SelfCheckSink {
    fn drop(&mut self) {
        self.tx = None;
        if let Some(h) = self.worker.take() {
            let _ = h.join();
        }
    }
}
