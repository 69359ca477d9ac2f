//! Any sink moved off the critical path: [`SideLane`] runs an inner [`Sink`] on its own thread at idle
//! priority (Linux SCHED_IDLE: it only gets CPU the pipeline leaves), fed copies of the published frames
//! ([`PublishedCopy`]) from a fixed pool.
//!
//! Why: a sink on the output lane adds its time to every frame's latency and, when the output lane falls
//! behind, makes the pipeline drop frames. Work that nothing downstream waits for (scoring depth against the
//! truth) belongs beside the pipeline, not in it. Nothing queued is lost: `finish` waits until the worker has
//! consumed every copy it was handed, and the counts say how many frames the inner sink saw. When every copy
//! is in use the frame is skipped by this sink only (counted; the pipeline never waits), except in blocking
//! mode (lossless runs), which waits for a free copy.
//!
//! Memory: the whole pool is made at the first frame, every buffer sized for the largest frame the pipeline's
//! buffers hold and written once, so the lane's resident memory is fixed from then on. (A pool made as the
//! worker fell behind, each copy growing as bigger clouds came, kept resident memory rising for minutes of a
//! soak: issue 42.)
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crossbeam_channel::{bounded, Receiver, Sender};
use glam::Vec3;
use serde::Serialize;

use abvs_runtime_core::error::{Result, RuntimeError};
use abvs_runtime_core::messages::{
    CloudPoint, DepthFrame, FoveaFrame, FrameMotion, Published, Rectification, RectifiedCamera, StereoPose,
};
use abvs_runtime_core::sink::Sink;
use abvs_runtime_core::stats::RunStats;

/// An owned copy of a [`Published`] frame, every field; its buffers are sized once for the largest frame
/// (`of`) and reused (no allocation per frame). A field added to `Published` is added to `fill` and `view`
/// here.
pub struct PublishedCopy {
    seq: u64,
    session_seq: u64,
    t_frame_ns: i64,
    theta: [[f64; 3]; 2],
    pose: StereoPose,
    rect: Rectification,
    cam: RectifiedCamera,
    depth: DepthFrame,
    left_rect: Vec<u8>,
    right_rect: Vec<u8>,
    disparity: Vec<f32>,
    confidence: Vec<f32>,
    has_confidence: bool,
    dense_disparity: Vec<f32>,
    has_dense: bool,
    motion: FrameMotion,
    /// The fovea's buffers (when the run has one) and whether this frame carries it.
    fovea: Option<Box<FoveaFrame>>,
    has_fovea: bool,
}

fn copy_into<T: Copy>(dst: &mut Vec<T>, src: &[T]) {
    dst.clear();
    dst.extend_from_slice(src);
}

/// An empty buffer with room for `n` values, each page of it written once: resident from the start, so a
/// cloud larger than the ones before adds nothing to the process's memory. (`vec![0; n]` would map zero
/// pages that become resident only as frames first write them.)
fn resident<T: Copy + Default>(n: usize) -> Vec<T> {
    let mut v = Vec::with_capacity(n);
    // (the buffer escapes before it is written: the write cannot be folded into a zeroed allocation)
    std::hint::black_box(&mut v);
    v.resize(n, T::default());
    std::hint::black_box(&mut v);
    v.clear();
    v
}

/// A fovea's buffers with every page written (non-zero: zeroed pages would map lazily, as `resident` says).
fn resident_fovea(w: u32, h: u32) -> FoveaFrame {
    let mut f = FoveaFrame::new(w, h);
    for b in [&mut f.left, &mut f.right, &mut f.valid] {
        b.fill(1);
    }
    f.depth.cloud.fill(CloudPoint::new(Vec3::ONE, 1));
    f.depth.pixel.fill(1);
    f
}

impl PublishedCopy {
    /// A copy of `out` in new buffers, each sized (and made resident) for the largest frame the pipeline's
    /// buffers hold: `out`'s full buffers, not only its valid points.
    pub fn of(out: &Published) -> Self {
        let mut c = PublishedCopy {
            seq: 0,
            session_seq: 0,
            t_frame_ns: 0,
            theta: *out.theta,
            pose: *out.pose,
            rect: *out.rect,
            cam: *out.cam,
            depth: DepthFrame {
                depth: resident(out.depth.depth.len()).into(),
                cloud: resident(out.depth.cloud.len()).into(),
                pixel: resident(out.depth.pixel.len()),
                ..DepthFrame::empty()
            },
            left_rect: resident(out.left_rect.len()),
            right_rect: resident(out.right_rect.len()),
            disparity: resident(out.disparity.len()),
            confidence: resident(out.confidence.map_or(0, <[f32]>::len)),
            has_confidence: false,
            dense_disparity: resident(out.dense_disparity.map_or(0, <[f32]>::len)),
            has_dense: false,
            motion: FrameMotion::new(),
            fovea: out.fovea.map(|f| Box::new(resident_fovea(f.cam.width, f.cam.height))),
            has_fovea: false,
        };
        c.fill(out);
        c
    }

    /// Copies `out` into this copy's buffers.
    pub fn fill(&mut self, out: &Published) {
        (self.seq, self.session_seq, self.t_frame_ns) = (out.seq, out.session_seq, out.t_frame_ns);
        (self.theta, self.pose, self.rect, self.cam) = (*out.theta, *out.pose, *out.rect, *out.cam);
        let (d, n) = (&mut self.depth, out.depth.n_points);
        (d.width, d.height, d.n_points) = (out.depth.width, out.depth.height, n);
        copy_into(d.depth.vec_mut(), &out.depth.depth);
        // only the valid points: the rest of the source's buffers is stale
        copy_into(d.cloud.vec_mut(), &out.depth.cloud[..n]);
        copy_into(&mut d.pixel, &out.depth.pixel[..n]);
        copy_into(&mut self.left_rect, out.left_rect);
        copy_into(&mut self.right_rect, out.right_rect);
        copy_into(&mut self.disparity, out.disparity);
        self.has_confidence = out.confidence.is_some();
        copy_into(&mut self.confidence, out.confidence.unwrap_or_default());
        self.has_dense = out.dense_disparity.is_some();
        copy_into(&mut self.dense_disparity, out.dense_disparity.unwrap_or_default());
        self.motion.copy_from(out.motion);
        self.has_fovea = false;
        if let (Some(dst), Some(src)) = (self.fovea.as_deref_mut(), out.fovea) {
            if (dst.cam.width, dst.cam.height) == (src.cam.width, src.cam.height) {
                dst.copy_from(src);
                self.has_fovea = true;
            }
        }
    }

    /// The copy as the frame the pipeline published.
    pub fn view(&self) -> Published<'_> {
        Published {
            seq: self.seq,
            session_seq: self.session_seq,
            t_frame_ns: self.t_frame_ns,
            theta: &self.theta,
            pose: &self.pose,
            rect: &self.rect,
            cam: &self.cam,
            depth: &self.depth,
            left_rect: &self.left_rect,
            right_rect: &self.right_rect,
            disparity: &self.disparity,
            confidence: self.has_confidence.then_some(&self.confidence[..]),
            dense_disparity: self.has_dense.then_some(&self.dense_disparity[..]),
            motion: &self.motion,
            fovea: self.fovea.as_deref().filter(|_| self.has_fovea),
        }
    }

    /// Points of the copied cloud (for tests).
    pub fn points(&self) -> &[CloudPoint] {
        &self.depth.cloud
    }
}

/// What a side lane counted (stats JSON under `{inner}_side_lane`).
#[derive(Debug, Clone, Default, Serialize)]
pub struct SideLaneStats {
    /// Frames the pipeline published to the sink.
    pub frames_in: u64,
    /// Copies in the lane's pool (made at the first frame, each sized for the largest frame).
    pub copies: u64,
    /// Frames the inner sink consumed (all that were copied: the lane is drained before the run ends).
    pub frames_consumed: u64,
    /// Frames not copied because every copy was still queued (the worker behind); never in blocking mode.
    pub frames_skipped: u64,
    /// Frames whose `consume` failed (the first error in `first_error`).
    pub frames_failed: u64,
    /// Copies still queued when the pipeline finished (consumed then, before the statistics).
    pub drained_at_finish: u64,
    /// The inner sink's time per frame on its thread (ms): mean and largest.
    pub consume_ms_mean: f64,
    /// Largest of the same (ms).
    pub consume_ms_max: f64,
    /// The first error of the inner sink.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub first_error: Option<String>,
}

struct Done<S> {
    sink: S,
    consumed: u64,
    failed: u64,
    ms_sum: f64,
    ms_max: f64,
    first_error: Option<String>,
}

/// An inner sink on its own idle-priority thread, fed copies from a pool of `slots`.
pub struct SideLane<S: Sink + 'static> {
    name: &'static str,
    blocking: bool,
    queue_tx: Option<Sender<Box<PublishedCopy>>>,
    free_rx: Receiver<Box<PublishedCopy>>,
    /// Copies not handed to the worker yet: the whole pool, made at the first frame. Boxed as the channels
    /// carry them, so a copy moves between the lane and the worker as a pointer.
    #[allow(clippy::vec_box)]
    unused: Vec<Box<PublishedCopy>>,
    /// Whether the pool has been made.
    made: bool,
    slots: usize,
    /// The inner sink's [`Sink::wants_dense_disparity`] (the sink itself lives on the worker).
    wants_dense: bool,
    st: SideLaneStats,
    worker: Option<JoinHandle<Done<S>>>,
}

/// Lowers the calling thread to idle priority: SCHED_IDLE, else the lowest nice level.
fn idle_priority() {
    #[cfg(target_os = "linux")]
    {
        let param = libc::sched_param { sched_priority: 0 };
        // SAFETY: plain system calls on the calling thread (pid 0) with a valid parameter struct.
        unsafe {
            if libc::sched_setscheduler(0, libc::SCHED_IDLE, &param) != 0 {
                libc::setpriority(libc::PRIO_PROCESS, 0, 19);
            }
        }
    }
}

impl<S: Sink + 'static> SideLane<S> {
    /// `sink` on its own thread with `slots` copies in flight at most; `blocking`: wait for a free copy
    /// instead of skipping a frame (lossless runs).
    pub fn new(sink: S, slots: usize, blocking: bool) -> Result<Self> {
        let (name, wants_dense) = (sink.name(), sink.wants_dense_disparity());
        if slots == 0 || slots > 256 {
            return Err(RuntimeError::Invalid(format!("{name} side lane: {slots} copies, expected 1..=256")));
        }
        let (queue_tx, queue_rx) = bounded::<Box<PublishedCopy>>(slots);
        let (free_tx, free_rx) = bounded::<Box<PublishedCopy>>(slots);
        let free = free_tx;
        let worker = std::thread::Builder::new()
            .name(format!("abvs-{name}"))
            .spawn(move || {
                idle_priority();
                let mut d = Done { sink, consumed: 0, failed: 0, ms_sum: 0.0, ms_max: 0.0, first_error: None };
                // ends when the sink drops its sender (finish) and the queue is drained
                for copy in queue_rx.iter() {
                    let t0 = Instant::now();
                    if let Err(e) = d.sink.consume(&copy.view()) {
                        d.failed += 1;
                        d.first_error.get_or_insert(format!("frame {}: {e}", copy.seq));
                    }
                    let ms = t0.elapsed().as_secs_f64() * 1e3;
                    (d.consumed, d.ms_sum, d.ms_max) = (d.consumed + 1, d.ms_sum + ms, d.ms_max.max(ms));
                    let _ = free.send(copy);
                }
                d
            })
            .map_err(|source| RuntimeError::Thread {
                what: format!("{name} side lane: starting its thread"),
                source,
            })?;
        Ok(SideLane {
            name,
            blocking,
            queue_tx: Some(queue_tx),
            free_rx,
            unused: Vec::new(),
            made: false,
            slots,
            wants_dense,
            st: SideLaneStats::default(),
            worker: Some(worker),
        })
    }

    fn alive(&self) -> bool {
        self.worker.as_ref().is_some_and(|w| !w.is_finished())
    }
}

impl<S: Sink + 'static> Sink for SideLane<S> {
    fn name(&self) -> &'static str {
        self.name
    }

    fn wants_dense_disparity(&self) -> bool {
        self.wants_dense
    }

    fn consume(&mut self, out: &Published) -> Result<()> {
        self.st.frames_in += 1;
        if !self.made {
            // the whole pool now, at its full size: nothing of the lane grows after the first frame
            self.unused = (0..self.slots).map(|_| Box::new(PublishedCopy::of(out))).collect();
            (self.made, self.st.copies) = (true, self.slots as u64);
        }
        let copy = match self.unused.pop().map_or_else(|| self.free_rx.try_recv(), Ok) {
            Ok(mut c) => {
                c.fill(out);
                Some(c)
            }
            Err(_) if self.blocking => loop {
                match self.free_rx.recv_timeout(Duration::from_millis(100)) {
                    Ok(mut c) => {
                        c.fill(out);
                        break Some(c);
                    }
                    Err(_) if self.alive() => continue,
                    Err(_) => break None,
                }
            },
            Err(_) => None,
        };
        let Some(copy) = copy else {
            self.st.frames_skipped += 1;
            return Ok(());
        };
        let sent = self.queue_tx.as_ref().map(|tx| tx.send(copy));
        match sent {
            Some(Ok(())) => Ok(()),
            _ => {
                self.st.frames_skipped += 1;
                Err(RuntimeError::Invalid(format!("{} side lane: its thread has ended", self.name)))
            }
        }
    }

    fn finish(&mut self, stats: &mut RunStats) {
        let queued = self.queue_tx.as_ref().map_or(0, |tx| tx.len()) as u64;
        // the worker consumes what is queued, then ends and hands the inner sink back
        self.queue_tx = None;
        let key = format!("{}_side_lane", self.name);
        match self.worker.take().map(|w| w.join()) {
            Some(Ok(mut d)) => {
                d.sink.finish(stats);
                self.st.frames_consumed = d.consumed;
                self.st.frames_failed = d.failed;
                self.st.drained_at_finish = queued;
                self.st.consume_ms_mean = if d.consumed > 0 { d.ms_sum / d.consumed as f64 } else { 0.0 };
                self.st.consume_ms_max = d.ms_max;
                self.st.first_error = d.first_error;
            }
            _ => self.st.first_error = Some("its thread panicked".into()),
        }
        stats.extra.insert(key, serde_json::to_value(&self.st).unwrap_or_default());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::{Arc, Mutex};

    /// Records the seq and the point count of every frame it sees, slowly.
    struct Slow(Arc<Mutex<Vec<(u64, usize)>>>);
    impl Sink for Slow {
        fn name(&self) -> &'static str {
            "slow"
        }
        fn consume(&mut self, out: &Published) -> Result<()> {
            std::thread::sleep(Duration::from_millis(5));
            self.0.lock().unwrap().push((out.seq, out.depth.n_points));
            Ok(())
        }
        fn finish(&mut self, stats: &mut RunStats) {
            stats.extra.insert("slow_finished".into(), serde_json::json!(true));
        }
    }

    fn frame(n: usize) -> (DepthFrame, RectifiedCamera) {
        // (a frame of 8x4 pixels, the first `n` of them valid points)
        let cam = RectifiedCamera::with_hfov(8, 4, 90.0);
        let mut d = DepthFrame::new(8, 4);
        d.n_points = n;
        for (i, p) in d.cloud.iter_mut().enumerate() {
            *p = CloudPoint::new(Vec3::splat(i as f32), i as u8);
        }
        (d, cam)
    }

    fn publish<S: Sink>(sink: &mut S, seq: u64, d: &DepthFrame, cam: &RectifiedCamera) {
        let id = abvs_eye::Pose::identity();
        let pose = StereoPose { rel_left: id, rel_right: id, left_to_right: id };
        let m = nalgebra::Matrix3::identity();
        let (theta, rect) = ([[0.0; 3]; 2], Rectification { rect_from_left: m, rect_from_right: m, baseline_m: 0.06 });
        let img = vec![0u8; 32];
        let disp = vec![0f32; 32];
        let motion = abvs_runtime_core::messages::FrameMotion::new();
        let p = Published {
            seq,
            session_seq: seq,
            t_frame_ns: 0,
            theta: &theta,
            pose: &pose,
            rect: &rect,
            cam,
            depth: d,
            left_rect: &img,
            right_rect: &img,
            disparity: &disp,
            confidence: None,
            dense_disparity: None,
            motion: &motion,
            fovea: None,
        };
        sink.consume(&p).unwrap();
    }

    #[test]
    fn blocking_lane_consumes_every_frame_in_order_with_its_own_copy() {
        let seen = Arc::new(Mutex::new(Vec::new()));
        let mut lane = SideLane::new(Slow(seen.clone()), 2, true).unwrap();
        let (d, cam) = frame(5);
        for seq in 0..10 {
            publish(&mut lane, seq, &d, &cam);
        }
        let mut stats = RunStats::new(&[]);
        lane.finish(&mut stats);
        let got = seen.lock().unwrap().clone();
        assert_eq!(got, (0..10).map(|s| (s, 5)).collect::<Vec<_>>());
        let st = &stats.extra["slow_side_lane"];
        assert_eq!((st["frames_in"].as_u64(), st["frames_consumed"].as_u64()), (Some(10), Some(10)));
        assert_eq!(st["frames_skipped"].as_u64(), Some(0));
        assert_eq!(stats.extra["slow_finished"], serde_json::json!(true));
    }

    #[test]
    fn the_whole_pool_is_made_at_the_first_frame_with_room_for_a_full_cloud() {
        let seen = Arc::new(Mutex::new(Vec::new()));
        let mut lane = SideLane::new(Slow(seen), 3, true).unwrap();
        // 5 valid points of the frame's 32: each copy still has room (resident) for all 32
        let (d, cam) = frame(5);
        publish(&mut lane, 0, &d, &cam);
        assert_eq!(lane.unused.len(), 2, "one copy handed to the worker, the other two made and waiting");
        for c in &lane.unused {
            let dep = &c.depth;
            let room = [dep.depth.capacity(), dep.cloud.capacity(), dep.pixel.capacity()];
            assert!(room.iter().all(|&n| n >= 32), "{room:?}");
            assert!(c.left_rect.capacity() >= 32 && c.disparity.capacity() >= 32);
        }
        let mut stats = RunStats::new(&[]);
        lane.finish(&mut stats);
        assert_eq!(stats.extra["slow_side_lane"]["copies"].as_u64(), Some(3));
    }

    #[test]
    fn a_lane_behind_skips_frames_and_counts_them_without_waiting() {
        let seen = Arc::new(Mutex::new(Vec::new()));
        let mut lane = SideLane::new(Slow(seen.clone()), 1, false).unwrap();
        let (d, cam) = frame(3);
        for seq in 0..20 {
            publish(&mut lane, seq, &d, &cam);
        }
        let mut stats = RunStats::new(&[]);
        lane.finish(&mut stats);
        let st = &stats.extra["slow_side_lane"];
        let (consumed, skipped) = (st["frames_consumed"].as_u64().unwrap(), st["frames_skipped"].as_u64().unwrap());
        assert_eq!(consumed + skipped, 20);
        assert!(skipped > 0);
        assert_eq!(seen.lock().unwrap().len() as u64, consumed);
    }
}
