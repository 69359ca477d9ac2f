//! The sink behind every ROS 2 output (`bridges::zenoh`, `sinks::mcap_log`): the output thread only copies
//! the frame into a pooled [`FrameSnapshot`] (the large arrays straight into their messages' buffers, lent
//! by the writer's pool when it has one: [`crate::ros2::buffers`]) and queues it; the sink's own thread
//! encodes the messages' fields around them ([`crate::ros2`]) and hands them to a [`Ros2Writer`] (the
//! network, a file). The queue is bounded: when the
//! writer falls behind, the oldest queued frame is dropped (counted) and the pipeline never waits on it,
//! except in blocking mode (lossless runs: every frame is written). The main depth image and cloud are not
//! copied when the writer's pool lends: the sink lends the frame's depth map and cloud their messages'
//! buffers before the depth stage runs ([`Sink::lend_depth`]) and queues the frame once every sink has read
//! it ([`Sink::frame_done`]).
use std::sync::atomic::{AtomicU32, AtomicUsize, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crossbeam_channel::{bounded, Receiver, Sender, TrySendError};
use serde::Serialize;

use crate::ros2::{cloud_layout, image_layout, BufferPool, EncodeError, Encoded, FrameSnapshot, Payload, Topic};
use abvs_runtime_core::error::{Result, RuntimeError};
use abvs_runtime_core::messages::{DepthFrame, Published};
use abvs_runtime_core::sink::Sink;
use abvs_runtime_core::stats::RunStats;

/// Why a ROS 2 output could not encode or write a frame.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// A message that did not encode.
    #[error(transparent)]
    Encode(#[from] EncodeError),
    /// Zenoh refused a publication.
    #[cfg(feature = "zenoh")]
    #[error("zenoh {key}: {source}")]
    Zenoh {
        /// The key expression.
        key: &'static str,
        /// What Zenoh said.
        #[source]
        source: ::zenoh::Error,
    },
    /// The MCAP writer failed.
    #[cfg(feature = "mcap")]
    #[error("{path}: {source}")]
    Mcap {
        /// The MCAP file.
        path: String,
        /// What the writer said.
        #[source]
        source: mcap::McapError,
    },
    /// Writing a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// What the system said.
        #[source]
        source: std::io::Error,
    },
    /// A lent buffer that is not the writer's own pool's.
    #[error("{0}: a message in a buffer the writer did not lend")]
    ForeignBuffer(&'static str),
    /// A topic the outputs do not have.
    #[error("{0}: not one of the ROS 2 outputs' topics")]
    UnknownTopic(&'static str),
    /// The output was closed (its thread ended).
    #[error("the output is closed")]
    Closed,
}

/// Where encoded messages go.
pub trait Ros2Writer: Send + 'static {
    /// Writes one message of the frame `seq` stamped `stamp_ns` (CLOCK_MONOTONIC). A large message's
    /// shared buffer is the snapshot's: a writer that keeps it past this call makes the next fill
    /// allocate a new one.
    fn write(
        &mut self,
        topic: &'static Topic,
        seq: u64,
        stamp_ns: i64,
        msg: Payload<'_>,
    ) -> std::result::Result<(), OutputError>;
    /// The pool the output thread writes the large messages into (Zenoh's shared memory); `None`: the
    /// snapshot's own buffers.
    fn pool(&self) -> Option<Arc<dyn BufferPool>> {
        None
    }
    /// The topics nobody receives now (bit i: [`crate::ros2::TOPICS`]`[i]`), kept current by the writer
    /// (Zenoh's matching status): they are neither copied nor encoded. `None` (a file): every topic.
    fn unwanted(&self) -> Option<Arc<AtomicU32>> {
        None
    }
    /// A message of the frame not written because nobody receives its topic.
    fn skipped(&mut self, _topic: &'static Topic) {}
    /// Ends the output (closes the file); what it reports goes into the stats.
    fn finish(&mut self) -> std::result::Result<serde_json::Value, OutputError> {
        Ok(serde_json::Value::Null)
    }
}

/// What a ROS 2 output counted (stats JSON under the sink's name).
#[derive(Debug, Clone, Default, Serialize)]
pub struct Ros2OutStats {
    /// Frames the pipeline handed to the sink.
    pub frames_in: u64,
    /// Frames whose five messages were all written.
    pub frames_written: u64,
    /// Frames dropped from the full queue (the oldest) because the writer was behind.
    pub frames_dropped: u64,
    /// Frames whose encoding or writing failed (the first error is in `last_error`).
    pub frames_failed: u64,
    /// Messages written, per frame five (eight with the fovea) less the skipped.
    pub messages: u64,
    /// Messages neither copied nor encoded because no subscriber matched their topic.
    pub messages_skipped: u64,
    /// Encoding + writing time per frame on the sink's thread (ms): median and largest.
    pub write_ms_p50: f64,
    /// Largest encoding + writing time per frame (ms).
    pub write_ms_max: f64,
    /// CPU time per frame of the copy on the pipeline's output thread (ms, thread CPU clock): the part of
    /// the output's cost that the sink's own thread (`abvs-<name>`, in the stats' `cpu`) does not show.
    pub copy_cpu_ms_per_frame: f64,
    /// Arrays the copy found still held by the writer (a new buffer allocated instead): 0 when the writer
    /// lets go of them after each frame, as Zenoh and MCAP do.
    pub arrays_reallocated: u64,
    /// Depth images whose array the depth stage wrote straight into the message's lent buffer (not copied:
    /// [`Sink::lend_depth`]).
    pub depth_in_place: u64,
    /// Clouds likewise.
    pub cloud_in_place: u64,
    /// The first error, when a frame failed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub last_error: Option<String>,
    /// What the writer reported at the end (e.g. the MCAP file's message counts).
    #[serde(skip_serializing_if = "serde_json::Value::is_null")]
    pub writer: serde_json::Value,
}

/// A ROS 2 output behind the pipeline's [`Sink`] trait.
pub struct Ros2OutSink {
    name: &'static str,
    blocking: bool,
    queue_tx: Option<Sender<Box<FrameSnapshot>>>,
    queue_rx: Receiver<Box<FrameSnapshot>>,
    free_tx: Sender<Box<FrameSnapshot>>,
    free_rx: Receiver<Box<FrameSnapshot>>,
    frames_in: u64,
    dropped: u64,
    copy_cpu_ns: i64,
    reallocated: u64,
    /// The writer's [`Ros2Writer::unwanted`].
    unwanted: Option<Arc<AtomicU32>>,
    /// The writer's [`Ros2Writer::pool`].
    pool: Option<Arc<dyn BufferPool>>,
    /// What this sink's buffers lent to depth maps and clouds are known by
    /// ([`abvs_runtime_core::lent::LentMap::lend`]).
    lender: usize,
    /// [`Ros2OutStats::depth_in_place`], [`Ros2OutStats::cloud_in_place`].
    in_place: [u64; 2],
    /// The frame consumed whose depth image or cloud awaits the buffer lent to it ([`Sink::frame_done`]).
    pending: Option<Box<FrameSnapshot>>,
    worker: Option<JoinHandle<Ros2OutStats>>,
}

/// Numbers the sinks' lent buffers apart.
static LENDERS: AtomicUsize = AtomicUsize::new(1);

impl Ros2OutSink {
    /// A sink named `name` (its stats key) writing through `writer` on its own thread, `queue` frames deep.
    /// `blocking`: wait for the writer instead of dropping (lossless runs).
    pub fn new<W: Ros2Writer>(name: &'static str, writer: W, queue: usize, blocking: bool) -> Result<Ros2OutSink> {
        if queue == 0 || queue > 1024 {
            return Err(RuntimeError::Invalid(format!("{name}: queue {queue} must be in 1..=1024")));
        }
        let (queue_tx, queue_rx) = bounded::<Box<FrameSnapshot>>(queue);
        // queue + the one the worker holds + the one being filled: one is always free or queued
        let (free_tx, free_rx) = bounded::<Box<FrameSnapshot>>(queue + 2);
        for _ in 0..queue + 2 {
            let _ = free_tx.send(Box::default());
        }
        let (rx, free) = (queue_rx.clone(), free_tx.clone());
        let (unwanted, pool) = (writer.unwanted(), writer.pool());
        let worker = std::thread::Builder::new()
            .name(format!("abvs-{name}"))
            .spawn(move || worker(writer, rx, free))
            .map_err(|source| RuntimeError::Thread { what: format!("{name}: starting its thread"), source })?;
        Ok(Ros2OutSink {
            name,
            blocking,
            queue_tx: Some(queue_tx),
            queue_rx,
            free_tx,
            free_rx,
            frames_in: 0,
            dropped: 0,
            copy_cpu_ns: 0,
            reallocated: 0,
            unwanted,
            pool,
            lender: LENDERS.fetch_add(1, Ordering::Relaxed),
            in_place: [0; 2],
            pending: None,
            worker: Some(worker),
        })
    }
}

fn worker<W: Ros2Writer>(
    mut writer: W,
    queue: Receiver<Box<FrameSnapshot>>,
    free: Sender<Box<FrameSnapshot>>,
) -> Ros2OutStats {
    let mut st = Ros2OutStats::default();
    let mut enc = Encoded::default();
    let mut times: Vec<f64> = Vec::new();
    // ends when the sink drops its sender (finish) and the queue is drained
    for mut snap in queue.iter() {
        let t0 = Instant::now();
        let (seq, stamp) = (snap.seq, snap.t_frame_ns);
        let r = enc.encode(&mut snap).map_err(OutputError::from).and_then(|()| {
            for topic in enc.skipped() {
                writer.skipped(topic);
                st.messages_skipped += 1;
            }
            for (topic, msg) in enc.messages(&mut snap) {
                writer.write(topic, seq, stamp, msg)?;
                st.messages += 1;
            }
            Ok(())
        });
        match r {
            Ok(()) => st.frames_written += 1,
            Err(e) => {
                st.frames_failed += 1;
                st.last_error.get_or_insert(format!("frame {}: {e}", snap.seq));
            }
        }
        // buffers lent for messages a failure left unsent go back to the pool now
        snap.release();
        if times.len() < 1_000_000 {
            times.push(t0.elapsed().as_secs_f64() * 1e3);
        }
        let _ = free.send(snap);
    }
    match writer.finish() {
        Ok(v) => st.writer = v,
        Err(e) => {
            st.last_error.get_or_insert(e.to_string());
        }
    }
    times.sort_by(f64::total_cmp);
    st.write_ms_p50 = times.get(times.len() / 2).copied().unwrap_or(0.0);
    st.write_ms_max = times.last().copied().unwrap_or(0.0);
    st
}

impl Sink for Ros2OutSink {
    fn name(&self) -> &'static str {
        self.name
    }

    fn consume(&mut self, out: &Published) -> Result<()> {
        if self.queue_tx.is_none() {
            return Ok(());
        }
        self.frames_in += 1;
        let alive = |w: &Option<JoinHandle<Ros2OutStats>>| w.as_ref().is_some_and(|w| !w.is_finished());
        let snap = if self.blocking {
            loop {
                match self.free_rx.recv_timeout(Duration::from_millis(100)) {
                    Ok(s) => break Some(s),
                    Err(_) if alive(&self.worker) => continue,
                    Err(_) => break None,
                }
            }
        } else {
            // no free buffer: the writer is behind, so the oldest queued frame makes room
            self.free_rx.try_recv().ok().or_else(|| {
                let old = self.queue_rx.try_recv().ok();
                self.dropped += old.is_some() as u64;
                old
            })
        };
        let Some(mut snap) = snap else {
            // the worker holds every buffer (it died): count the frame as dropped
            self.dropped += 1;
            return Ok(());
        };
        let cpu0 = abvs_runtime_core::cpu::thread_cpu_ns();
        let skip = self.unwanted.as_ref().map_or(0, |u| u.load(Ordering::Relaxed));
        self.reallocated += snap.fill(out, skip, self.pool.as_deref(), Some(self.lender)) as u64;
        self.copy_cpu_ns += abvs_runtime_core::cpu::thread_cpu_ns() - cpu0;
        if snap.awaits_depth {
            // the depth map or cloud is in this sink's buffer: sent once every sink has read it (frame_done)
            self.pending = Some(snap);
            return Ok(());
        }
        self.queue(snap)
    }

    fn lend_depth(&mut self, depth: &mut DepthFrame) -> Result<bool> {
        let (Some(pool), Some(_)) = (&self.pool, &self.queue_tx) else { return Ok(false) };
        // a topic nobody receives has no message to write into
        let unwanted = self.unwanted.as_ref().map_or(0, |u| u.load(Ordering::Relaxed));
        let cpu0 = abvs_runtime_core::cpu::thread_cpu_ns();
        // a buffer the map refuses (misaligned) goes back to the pool: the map is copied, the usual way
        let mut lent = false;
        if unwanted & 1 == 0 {
            let layout = image_layout(depth.depth.len());
            lent |= pool.lend(layout.len()).is_some_and(|b| depth.depth.lend(b, layout.head, self.lender).is_ok());
        }
        if unwanted & 1 << 2 == 0 {
            // room for every pixel (the points are not counted yet): sent shortened to the frame's points
            let layout = cloud_layout(depth.cloud.len());
            lent |= pool.lend(layout.len()).is_some_and(|b| depth.cloud.lend(b, layout.head, self.lender).is_ok());
        }
        self.copy_cpu_ns += abvs_runtime_core::cpu::thread_cpu_ns() - cpu0;
        Ok(lent)
    }

    fn frame_done(&mut self, depth: &mut DepthFrame) -> Result<()> {
        // a buffer lent for a frame that was not consumed (failed, dropped, topic unwanted by then) is
        // dropped here: back to its pool
        let bufs = [depth.depth.take_lent(self.lender), depth.cloud.take_lent(self.lender)];
        let Some(mut snap) = self.pending.take() else { return Ok(()) };
        let cpu0 = abvs_runtime_core::cpu::thread_cpu_ns();
        for (cloud, buf) in bufs.into_iter().enumerate() {
            // (a buffer the snapshot does not wait for was lent for a topic unwanted by the time it consumed)
            if let Some(b) = buf {
                self.in_place[cloud] += snap.adopt(b, cloud == 1).is_ok() as u64;
            }
        }
        self.copy_cpu_ns += abvs_runtime_core::cpu::thread_cpu_ns() - cpu0;
        if snap.awaits_depth {
            // cannot happen (the buffers are lent at the arrays' sizes and only this sink takes them): not sent
            snap.release();
            snap.awaits_depth = false;
            let _ = self.free_tx.try_send(snap);
            self.dropped += 1;
            return Err(RuntimeError::Invalid(format!("{}: a lent buffer did not come back", self.name)));
        }
        self.queue(snap)
    }

    fn finish(&mut self, stats: &mut RunStats) {
        // (a frame awaiting its depth buffer would be one whose frame_done never came: not sent)
        self.dropped += self.pending.take().is_some() as u64;
        self.finish_worker(stats);
    }
}

impl Ros2OutSink {
    /// Hands a filled snapshot to the worker; when its queue is full, the oldest queued frame makes room
    /// (blocking mode: waits).
    fn queue(&mut self, mut snap: Box<FrameSnapshot>) -> Result<()> {
        let Some(tx) = &self.queue_tx else { return Ok(()) };
        let alive = |w: &Option<JoinHandle<Ros2OutStats>>| w.as_ref().is_some_and(|w| !w.is_finished());
        loop {
            match tx.try_send(snap) {
                Ok(()) => return Ok(()),
                Err(TrySendError::Full(back)) if self.blocking && alive(&self.worker) => {
                    snap = back;
                    std::thread::sleep(Duration::from_micros(200));
                }
                Err(TrySendError::Full(back)) => {
                    // the oldest queued frame makes room (the worker took none since the free one came)
                    snap = back;
                    match self.queue_rx.try_recv() {
                        Ok(old) => {
                            self.dropped += 1;
                            let _ = self.free_tx.try_send(old);
                        }
                        Err(_) if !alive(&self.worker) => {
                            self.dropped += 1;
                            return Err(RuntimeError::Invalid(format!("{}: its thread has ended", self.name)));
                        }
                        Err(_) => {}
                    }
                }
                Err(TrySendError::Disconnected(_)) => {
                    return Err(RuntimeError::Invalid(format!("{}: its thread has ended", self.name)))
                }
            }
        }
    }

    fn finish_worker(&mut self, stats: &mut RunStats) {
        // the worker writes what is queued, then ends
        self.queue_tx = None;
        let mut st = match self.worker.take().map(|w| w.join()) {
            Some(Ok(st)) => st,
            _ => Ros2OutStats { last_error: Some("its thread panicked".into()), ..Default::default() },
        };
        st.frames_in = self.frames_in;
        st.frames_dropped = self.dropped;
        st.copy_cpu_ms_per_frame = self.copy_cpu_ns as f64 / 1e6 / self.frames_in.max(1) as f64;
        st.arrays_reallocated = self.reallocated;
        [st.depth_in_place, st.cloud_in_place] = self.in_place;
        stats.extra.insert(self.name.into(), serde_json::to_value(&st).unwrap_or_default());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ros2::buffers::LentBuf;
    use abvs_eye::Pose;
    use abvs_runtime_core::messages::{CloudPoint, FrameMotion, Rectification, RectifiedCamera, StereoPose};
    use std::sync::Mutex;

    /// (topic, whether in a lent buffer, bytes) of every message written.
    type Written = Arc<Mutex<Vec<(&'static str, bool, Vec<u8>)>>>;

    /// A lent buffer that counts itself back to its pool when dropped.
    struct Counted(Vec<u8>, Arc<AtomicUsize>);
    impl AsRef<[u8]> for Counted {
        fn as_ref(&self) -> &[u8] {
            &self.0
        }
    }
    impl AsMut<[u8]> for Counted {
        fn as_mut(&mut self) -> &mut [u8] {
            &mut self.0
        }
    }
    impl Drop for Counted {
        fn drop(&mut self) {
            self.1.fetch_sub(1, Ordering::Relaxed);
        }
    }

    /// Lends every buffer, counting those out.
    struct Pool(Arc<AtomicUsize>);
    impl BufferPool for Pool {
        fn lend(&self, len: usize) -> Option<Box<dyn LentBuf>> {
            self.0.fetch_add(1, Ordering::Relaxed);
            // not zeroed, as a shared-memory buffer from a pool is not
            Some(Box::new(Counted(vec![0xa5; len], self.0.clone())))
        }
    }

    struct Recorder {
        written: Written,
        pool: Option<Arc<dyn BufferPool>>,
        unwanted: Arc<AtomicU32>,
    }
    impl Ros2Writer for Recorder {
        fn write(
            &mut self,
            t: &'static Topic,
            _: u64,
            _: i64,
            msg: Payload<'_>,
        ) -> std::result::Result<(), OutputError> {
            let lent = matches!(msg, Payload::Lent(..));
            self.written.lock().unwrap().push((t.topic, lent, msg.bytes().to_vec()));
            Ok(())
        }
        fn pool(&self) -> Option<Arc<dyn BufferPool>> {
            self.pool.clone()
        }
        fn unwanted(&self) -> Option<Arc<AtomicU32>> {
            Some(self.unwanted.clone())
        }
    }

    #[test]
    fn a_depth_map_and_cloud_written_in_the_lent_messages_are_sent_as_the_copied_ones_and_unsent_buffers_go_back() {
        let out = Arc::new(AtomicUsize::new(0));
        let unwanted = Arc::new(AtomicU32::new(0));
        let (lent_w, copied_w) = (Written::default(), Written::default());
        let pool: Arc<dyn BufferPool> = Arc::new(Pool(out.clone()));
        let rec = |written: &Written, pool, unwanted| Recorder { written: written.clone(), pool, unwanted };
        // as the runner holds them: the first lends, the second (a file: no pool, every topic) copies
        let mut sinks = [
            Ros2OutSink::new("zenoh", rec(&lent_w, Some(pool), unwanted.clone()), 4, true).unwrap(),
            Ros2OutSink::new("mcap", rec(&copied_w, None, Arc::default()), 4, true).unwrap(),
        ];
        let cam = RectifiedCamera::with_hfov(5, 3, 90.0);
        let pose =
            StereoPose { rel_left: Pose::identity(), rel_right: Pose::identity(), left_to_right: Pose::identity() };
        let rect = Rectification {
            rect_from_left: nalgebra::Matrix3::identity(),
            rect_from_right: nalgebra::Matrix3::identity(),
            baseline_m: 0.06,
        };
        let motion = FrameMotion::new();
        let mut depth = DepthFrame::new(5, 3);
        // frame 0 sent; frame 1 fails before the sinks; frame 2's depth topic has no subscriber; frame 3's
        // cloud topic has none; frame 4's depth topic loses its subscriber between the lending and the sinks
        let frames = [(0u64, true, 0u32, 0u32), (1, false, 0, 0), (2, true, 1, 1), (3, true, 4, 4), (4, true, 0, 1)];
        for (seq, consumed, unwanted_lent, unwanted_consumed) in frames {
            unwanted.store(unwanted_lent, Ordering::Relaxed);
            let lent = sinks.iter_mut().map(|s| s.lend_depth(&mut depth).unwrap()).collect::<Vec<_>>();
            assert_eq!(lent, [true, false], "frame {seq}");
            assert_eq!(depth.depth.lent_by().is_some(), unwanted_lent & 1 == 0);
            assert_eq!(depth.cloud.lent_by().is_some(), unwanted_lent & 4 == 0);
            // the depth stage, in place: every fourth pixel invalid, the others points
            depth.n_points = 0;
            for i in 0..depth.depth.len() {
                depth.depth[i] = if i % 4 == 0 { f32::NAN } else { seq as f32 + i as f32 * 0.125 };
                if i % 4 != 0 {
                    let n = depth.n_points;
                    depth.cloud[n] = CloudPoint::new(glam::Vec3::new(i as f32, seq as f32, 0.5), i as u8);
                    depth.n_points += 1;
                }
            }
            unwanted.store(unwanted_consumed, Ordering::Relaxed);
            if consumed {
                let p = Published {
                    seq,
                    session_seq: seq,
                    t_frame_ns: 1_000_000_007 * seq as i64,
                    theta: &[[0.0; 3]; 2],
                    pose: &pose,
                    rect: &rect,
                    cam: &cam,
                    depth: &depth,
                    left_rect: &[],
                    right_rect: &[],
                    disparity: &[],
                    confidence: None,
                    dense_disparity: None,
                    motion: &motion,
                    fovea: None,
                };
                sinks.iter_mut().for_each(|s| s.consume(&p).unwrap());
            }
            sinks.iter_mut().for_each(|s| s.frame_done(&mut depth).unwrap());
            assert_eq!((depth.depth.lent_by(), depth.cloud.lent_by()), (None, None));
        }
        let mut stats = RunStats::new(&[]);
        sinks.iter_mut().for_each(|s| s.finish(&mut stats));
        // every buffer came back: the sent ones from the writer, the failed frame's and the refused ones
        assert_eq!(out.load(Ordering::Relaxed), 0);
        let (lent_w, copied_w) = (lent_w.lock().unwrap(), copied_w.lock().unwrap());
        let msgs =
            |w: &[(&'static str, bool, Vec<u8>)], topic| w.iter().filter(|m| m.0 == topic).cloned().collect::<Vec<_>>();
        // the depth images: frames 0 and 3 in lent buffers, byte for byte the copied ones; frames 2 and 4 only
        // in the file
        let (lent_d, copied_d) = (msgs(&lent_w, "/abvs/depth"), msgs(&copied_w, "/abvs/depth"));
        assert_eq!((lent_d.len(), copied_d.len()), (2, 4));
        assert!(lent_d.iter().all(|m| m.1) && lent_d[0].2 == copied_d[0].2 && lent_d[1].2 == copied_d[2].2);
        assert_eq!(lent_d[0].2.len(), image_layout(15).len());
        // the clouds: frames 0, 2 and 4 in lent buffers shortened to their 11 points (frame 4's lent though its
        // depth image was then copied); frame 3's only in the file
        let (lent_c, copied_c) = (msgs(&lent_w, "/abvs/points"), msgs(&copied_w, "/abvs/points"));
        assert_eq!((lent_c.len(), copied_c.len()), (3, 4));
        assert!(lent_c.iter().all(|m| m.1 && m.2.len() == cloud_layout(11).len()));
        assert!([(0, 0), (1, 1), (2, 3)].iter().all(|&(l, c)| lent_c[l].2 == copied_c[c].2));
        // every other message alike in both
        let rest = |w: &[(&'static str, bool, Vec<u8>)]| {
            w.iter()
                .filter(|m| !["/abvs/depth", "/abvs/points"].contains(&m.0))
                .map(|m| (m.0, m.2.clone()))
                .collect::<Vec<_>>()
        };
        assert_eq!(rest(&lent_w), rest(&copied_w));
        let zenoh = &stats.extra["zenoh"];
        assert_eq!((zenoh["frames_written"].as_u64(), zenoh["frames_dropped"].as_u64()), (Some(4), Some(0)));
        assert_eq!((zenoh["depth_in_place"].as_u64(), zenoh["cloud_in_place"].as_u64()), (Some(2), Some(3)));
        assert_eq!(stats.extra["mcap"]["depth_in_place"].as_u64(), Some(0));
    }
}
