//! The sink and its worker thread: pooled jobs, idle-priority checking, the summary at the end.
use super::*;

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
        let mut log = match &cfg.log {
            Some(p) => {
                let f = std::fs::File::create(p).map_err(|e| RuntimeError::File {
                    path: p.clone(),
                    line: None,
                    msg: e.to_string(),
                })?;
                Some((std::io::BufWriter::new(f), p.clone()))
            }
            None => None,
        };
        if let Some((w, p)) = &mut log {
            writeln!(w, "{LOG_HEADER}").map_err(|e| RuntimeError::File {
                path: p.clone(),
                line: None,
                msg: e.to_string(),
            })?;
        }
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
                                if let Err(e) = writeln!(w, "{}", log_row(&c)) {
                                    log::warn!("self-check log {}: {e}", p.display());
                                    log = None;
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
                if let Some((mut w, p)) = log {
                    if let Err(e) = w.flush() {
                        log::warn!("self-check log {}: {e}", p.display());
                    }
                }
                sum
            })
            .map_err(|e| RuntimeError::Invalid(format!("self-check: starting its thread: {e}")))?;
        Ok(SelfCheckSink { cfg, tx: Some(tx), free: free_rx, worker: Some(worker), skipped: 0 })
    }
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
