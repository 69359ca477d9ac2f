//! The closed-loop simulation of the whole head (`abvs run --source sim`, `[source.sim]`): a
//! [`PairSource`] whose drive board executes the runtime's commands and whose cameras are rendered from
//! the true link angles.
//!
//! - The head of a seed: both units (their true physics, every effect on) and the stereo rig, drawn as
//!   `abvs sim session --seed` draws them ([`crate::synth::units_for`], [`crate::synth::rig`]), and the scene
//!   "abvs-scene/1" of that seed.
//! - The drive board: at power-up each eye rolls its links through the index markers
//!   ([`crate::servo_board::ServoBoard::startup`]); the runtime's own homing ([`EncoderTracker`]) decides the
//!   home counts from those frames; then the board moves the eyes home and they rest there. A move command
//!   (the gaze controller's, through [`BoardLink::send_move`]) is a minimum-jerk profile in link space from where
//!   the links are when it arrives to the target counts, over the commanded duration (a move under way is
//!   replaced); the motors track it to the count. The encoders read the links rounded to counts, stamped late
//!   by each unit's true encoder latency, at 1 kHz.
//! - Virtual time: frame k's instant is `t0 + k / fps`; the controller acts on a frame
//!   [`CONTROL_DELAY_MS`] after its last row's exposure ended plus the units' encoder latency (when the
//!   time-alignment stage has the encoder samples it waits for), so its commands move the eyes from then. The
//!   source renders frame k only once the gaze stage is done with frame k - 1 ([`BoardLink::frame_done`]):
//!   lockstep, so every frame is drawn from every command that precedes it, whatever the computer's speed: a
//!   run is deterministic, bit for bit, and runs as fast as rendering allows (always lossless).
//! - Rendering: each eye's camera from the true unit at the true link angles at every row's time samples,
//!   with rolling shutter and motion blur, exactly as `abvs sim session` renders (`synth::EyeView`).
//! - Truth: each frame's true poses (both eyes at the frame's instant, the left eye at its row nodes) and true
//!   link angles go to a bounded [`TruthFeed`], which the depth scoring ([`crate::truth::TruthSink::for_head`])
//!   and the gaze scoring ([`crate::gaze_score::GazeScore`]) read by seq.
//! - Goals: a gaze script ([`crate::gaze_script`]) posts each goal at the first frame whose instant is at or
//!   after its time; goals from other processes (the iceoryx2 gaze service) reach the same mailbox and are
//!   taken at the next frame. Without goals the eyes hold home.
use std::collections::VecDeque;
use std::path::Path;
use std::sync::{Arc, Condvar, Mutex, OnceLock};
use std::time::Duration;

use abvs_camera::{Camera, StereoCalibration};
use abvs_eye::encoder::COUNTS_PER_REV;
use abvs_eye::saccade::{MinJerk, PEAK_SPEED_DEG_S};
use abvs_eye::unit::{UnitFk, UnitStream};
use abvs_eye::{Pose, UnitModel};
use abvs_render::{RayTable, Scene};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use abvs_board::protocol::BoardFrame;
use abvs_board::tracker::EncoderTracker;
use abvs_runtime::gaze::GazeHandle;
use abvs_runtime_core::error::{Result, RuntimeError};
use abvs_runtime_core::messages::{EncoderSample, SourcePair};
use abvs_runtime_core::source::BoardLink;
use abvs_runtime_core::source::{EncoderFeed, PairSource};
use abvs_runtime_core::stats::RunStats;

use crate::gaze_script::{GazeScript, ScriptGoal};
use crate::servo_board::ServoBoard;
use crate::synth::{EyeView, FrameTiming, TRUTH_ROW_NODES};

/// How long after a frame's last row stopped exposing the gaze controller acts on it (ms), beyond the units'
/// encoder latency: the time-alignment stage waits for the encoder samples up to 20 ms past the frame (its
/// speed estimate), as it would live; the controller's commands cannot come earlier.
pub const CONTROL_DELAY_MS: f64 = 20.0;

/// Virtual time of the board's power-up (ns): the frames' clock starts here, far from 0.
const EPOCH_NS: i64 = 1_000_000_000;

/// How long the source waits for the gaze stage to finish the previous frame before it ends the run (a
/// stage that failed the frame: the run ends with the reason, never hangs).
pub const LOCKSTEP_TIMEOUT: Duration = Duration::from_secs(120);

/// Frames of truth kept for the sinks that read it (they run at most a few frames behind the source: the
/// pool's frames plus the side lane's copies).
const TRUTH_FRAMES: usize = 128;

/// Moves remembered per eye: a pursuit sends one per frame, and the encoders and the renderer ask for the
/// links' positions at most a frame or two back.
const MOVE_HISTORY: usize = 64;

fn inv(e: impl std::fmt::Display) -> RuntimeError {
    RuntimeError::Invalid(e.to_string())
}

/// The simulated head's settings (`[source.sim]`).
#[derive(Debug, Clone)]
pub struct HeadSpec {
    pub seed: u64,
    pub width: u32,
    pub height: u32,
    pub fps: f64,
    pub exposure_ms: f64,
    pub readout_ms: f64,
    /// Samples per pixel side of the renderer (1: one ray a pixel).
    pub supersample: u32,
    pub noise_sigma: f64,
    pub threads: usize,
}

impl HeadSpec {
    /// From the runtime configuration's `[source.sim]`.
    pub fn from_config(c: &abvs_runtime_core::config::SimConfig) -> HeadSpec {
        HeadSpec {
            seed: c.seed,
            width: c.width,
            height: c.height,
            fps: c.fps,
            exposure_ms: c.exposure_ms,
            readout_ms: c.readout_ms,
            supersample: 1,
            noise_sigma: 1.5,
            threads: std::thread::available_parallelism().map_or(2, |n| n.get()),
        }
    }
}

/// The true head of a seed: units, rig, lens and scene.
pub struct Head {
    pub spec: HeadSpec,
    pub units: [UnitModel; 2],
    /// T_lH^rH (metres).
    pub home_left_to_right: Pose,
    pub stereo: StereoCalibration,
    pub camera: Camera,
    pub scene: Scene,
}

impl Head {
    /// The head `spec.seed` picks (the same units, rig and scene as `abvs sim session --seed`).
    pub fn new(spec: &HeadSpec) -> Result<Head> {
        let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
        let (home_left_to_right, stereo) = crate::synth::rig(&mut rng, spec.width, spec.height);
        Ok(Head {
            spec: spec.clone(),
            units: crate::synth::units_for(spec.seed),
            home_left_to_right,
            camera: stereo.left,
            stereo,
            scene: crate::synth::scene(spec.seed)?,
        })
    }

    /// The calibration a user of these units would have, in `dir` (stereo.yaml, eye0, eye1: what
    /// `calibration.dir` names): each eye's FK fitted with `method` on a simulated calibration dataset of its
    /// unit (measurements, not the truth), the stereo calibration at home. Made once: a directory that holds
    /// it already (for this seed, method and size) is reused.
    pub fn calibrate(&self, dir: &Path, method: abvs_calib::methods::Method) -> Result<()> {
        let stamp = format!(
            "abvs-sim-head seed {} method {} size {}x{}\n",
            self.spec.seed, method, self.spec.width, self.spec.height
        );
        let stamp_path = dir.join("sim-head.txt");
        if std::fs::read_to_string(&stamp_path).is_ok_and(|s| s == stamp) {
            return Ok(());
        }
        let io = |p: &Path, e: &dyn std::fmt::Display| RuntimeError::File {
            path: p.to_path_buf(),
            line: None,
            msg: e.to_string(),
        };
        std::fs::create_dir_all(dir).map_err(|e| io(dir, &e))?;
        self.stereo.write_yaml(dir.join("stereo.yaml")).map_err(inv)?;
        for (eye, unit) in self.units.iter().enumerate() {
            let d = dir.join(format!("eye{eye}"));
            // the same measurement and fit seeds as `abvs sim session`
            crate::synth::calibrate_unit(unit, method, 6.0, self.spec.seed * 7 + eye as u64, self.spec.seed, &d)?;
        }
        std::fs::write(&stamp_path, stamp).map_err(|e| io(&stamp_path, &e))
    }
}

/// One eye's links over time (raw counts, continuous): where they rested, then each move from where the
/// links were when it arrived.
#[derive(Debug, Clone)]
struct Trajectory {
    rest: [f64; 3],
    /// (start, virtual ns; the move), in start order.
    moves: VecDeque<(i64, MinJerk)>,
}

impl Trajectory {
    fn at(&self, t_ns: i64) -> [f64; 3] {
        match self.moves.iter().rev().find(|(s, _)| *s <= t_ns) {
            Some((s, m)) => {
                let t = (t_ns - s) as f64 * 1e-9;
                if t >= m.duration_s {
                    m.to
                } else {
                    m.at(t)
                }
            }
            None => self.moves.front().map_or(self.rest, |(_, m)| m.from),
        }
    }

    fn command(&mut self, t_ns: i64, to: [f64; 3], duration_s: f64) {
        let from = self.at(t_ns);
        self.moves.push_back((t_ns, MinJerk { from, to, duration_s }));
        while self.moves.len() > MOVE_HISTORY {
            self.moves.pop_front();
        }
    }
}

/// One frame's truth, as the sinks read it.
#[derive(Debug, Clone)]
pub struct FrameTruth {
    pub seq: u64,
    /// The frame's instant (its middle row's mid-exposure; virtual ns).
    pub t_frame_ns: i64,
    /// Each eye's true camera pose at the frame's instant in the left home camera frame (metres): the world.
    pub world_from_cam: [Pose; 2],
    /// The left eye's true pose relative to its home (metres) at the frame's instant, and at its row nodes
    /// (node n at row n (H - 1) / N's mid-exposure), as `truth/row_poses.csv` gives them.
    pub left_rel: Pose,
    pub left_rows: Vec<Pose>,
    /// True link angles (deg, homed) at the frame's instant.
    pub theta_deg: [[f64; 3]; 2],
    /// The largest true link travel over the frame's exposure window, either eye (deg): a frame exposed while
    /// the eyes moved.
    pub travel_deg: f64,
}

/// The head's truth for the sinks: the latest `TRUTH_FRAMES` frames by seq (bounded).
#[derive(Debug, Default)]
pub struct TruthFeed {
    ring: Mutex<VecDeque<FrameTruth>>,
}

impl TruthFeed {
    fn push(&self, t: FrameTruth) {
        let mut r = self.ring.lock().expect("truth feed");
        if r.len() == TRUTH_FRAMES {
            r.pop_front();
        }
        r.push_back(t);
    }

    /// The truth of frame `seq`, while it is held.
    pub fn get(&self, seq: u64) -> Option<FrameTruth> {
        let r = self.ring.lock().expect("truth feed");
        let first = r.front()?.seq;
        r.get(seq.checked_sub(first)? as usize).filter(|t| t.seq == seq).cloned()
    }
}

/// What the source, the board link and the encoder feed share.
struct Board {
    traj: [Trajectory; 2],
    /// Raw counts at theta = 0 as the runtime's homing decided them.
    home: [[i64; 3]; 2],
    /// The newest encoder sample handed to the runtime (virtual ns).
    last_record_ns: Option<i64>,
    /// The last frame the gaze stage is done with.
    done: Option<u64>,
    /// The virtual instant of the frame the controller is acting on (its commands start then).
    pending_now: Option<i64>,
    commands: u64,
}

struct Shared {
    board: Mutex<Board>,
    done: Condvar,
    /// Each eye's encoder latency (ns): samples stamped this late.
    latency_ns: [i64; 2],
    control_delay_ns: i64,
}

impl Shared {
    /// True link angles (deg, homed) of `eye` at `t_ns`.
    fn theta(b: &Board, eye: usize, t_ns: i64) -> [f64; 3] {
        let p = b.traj[eye].at(t_ns);
        std::array::from_fn(|i| (p[i] - b.home[eye][i] as f64) * 360.0 / COUNTS_PER_REV as f64)
    }
}

/// The head's drive board as the gaze controller sees it.
struct SimBoardLink {
    shared: Arc<Shared>,
}

impl BoardLink for SimBoardLink {
    fn home_counts(&self) -> Option<[[i64; 3]; 2]> {
        // the moves are absolute targets relative to home: the raw home counts themselves are the board's
        Some(self.shared.board.lock().expect("sim board").home)
    }

    fn last_record_ns(&self) -> Option<i64> {
        self.shared.board.lock().expect("sim board").last_record_ns
    }

    fn send_move(&mut self, target_counts: [[i64; 3]; 2], duration_us: u32) -> std::result::Result<(), String> {
        // (the virtual instant of the command: the frame the controller acts on, `virtual_now_ns`)
        let mut b = self.shared.board.lock().expect("sim board");
        let now = b.pending_now.ok_or("sim board: a command outside a frame")?;
        for (e, t) in target_counts.iter().enumerate() {
            let raw = std::array::from_fn(|i| (b.home[e][i] + t[i]) as f64);
            b.traj[e].command(now, raw, f64::from(duration_us) * 1e-6);
        }
        b.commands += 1;
        Ok(())
    }

    fn virtual_now_ns(&self, exposure_end_ns: i64) -> Option<i64> {
        let now = exposure_end_ns + self.shared.control_delay_ns;
        self.shared.board.lock().expect("sim board").pending_now = Some(now);
        Some(now)
    }

    fn frame_done(&mut self, seq: u64) {
        let mut b = self.shared.board.lock().expect("sim board");
        b.done = Some(b.done.map_or(seq, |d| d.max(seq)));
        b.pending_now = None;
        self.shared.done.notify_all();
    }
}

/// The head's encoder stream: 1 kHz samples of both eyes, stamped late by each unit's latency, rounded to counts.
struct SimEncoders {
    shared: Arc<Shared>,
    next_ns: i64,
}

/// Encoder sample period (ns): 1 kHz.
const ENCODER_PERIOD_NS: i64 = 1_000_000;

impl EncoderFeed for SimEncoders {
    fn feed(&mut self, t_ns: i64, push: &mut dyn FnMut(usize, EncoderSample)) {
        let mut b = self.shared.board.lock().expect("sim board");
        while self.next_ns <= t_ns {
            for e in 0..2 {
                let p = b.traj[e].at(self.next_ns - self.shared.latency_ns[e]);
                let deg = |i: usize| (p[i].round() as i64 - b.home[e][i]) as f64 * 360.0 / COUNTS_PER_REV as f64;
                push(e, EncoderSample { t_s: self.next_ns as f64 * 1e-9, theta_deg: [deg(0), deg(1), deg(2)] });
            }
            b.last_record_ns = Some(self.next_ns);
            self.next_ns += ENCODER_PERIOD_NS;
        }
    }
}

/// Where the goals of a script go: the runtime's gaze handle, set once the runtime is assembled.
pub type GoalSlot = Arc<OnceLock<GazeHandle>>;

/// The simulated head as the runtime's [`PairSource`] (see the module doc).
pub struct SimSource {
    head: Head,
    shared: Arc<Shared>,
    truth: Arc<TruthFeed>,
    goals: GoalSlot,
    script: VecDeque<ScriptGoal>,
    fks: [UnitFk; 2],
    streams: [UnitStream; 2],
    rays: RayTable,
    world_from_rhome: Pose,
    /// Frame 0's instant (virtual ns).
    t0_ns: i64,
    next: u64,
    left: Vec<u8>,
    right: Vec<u8>,
    board_taken: bool,
    /// Goals the script posted.
    posted: u64,
    /// Why the run ended early, if it did.
    ended: Option<String>,
}

impl SimSource {
    /// The head of `head.spec`, homed and resting at home, with the goals of `script` to play.
    pub fn new(head: Head, script: Option<GazeScript>) -> Result<SimSource> {
        let spec = head.spec.clone();
        // power-up: the start-up roll through the index markers, homed by the runtime's own homing
        let mut servo = ServoBoard::from_seed(spec.seed ^ 0xb0a2d);
        let samples = servo.startup(1000);
        let mut tracker = EncoderTracker::new();
        let mut records = Vec::new();
        for (k, (t_us, eye, counts, index)) in samples.iter().enumerate() {
            let f = BoardFrame { seq: k as u16, board_time_us: *t_us, eye: *eye, counts: *counts, index: *index };
            tracker.feed(&f.encode(), EPOCH_NS + *t_us as i64 * 1000, &mut records);
        }
        let homes = tracker.stats().home_counts;
        let (Some(h0), Some(h1)) = (homes[0], homes[1]) else {
            return Err(RuntimeError::Invalid(format!(
                "sim head {}: the start-up roll did not home both eyes",
                spec.seed
            )));
        };
        let home = [h0, h1];
        let roll_end_ns = EPOCH_NS + servo.startup_end_us(1000) as i64 * 1000;
        // where the roll left the links, then home at the eyes' peak speed
        let rest: [[f64; 3]; 2] =
            std::array::from_fn(|e| servo.sample(e as u8, servo.startup_end_us(1000)).2.map(f64::from));
        let mut traj = rest.map(|r| Trajectory { rest: r, moves: VecDeque::new() });
        let mut home_end_ns = roll_end_ns;
        for (e, t) in traj.iter_mut().enumerate() {
            let to = home[e].map(|c| c as f64);
            let deg = |c: [f64; 3]| c.map(|x| x * 360.0 / COUNTS_PER_REV as f64);
            let m = MinJerk::with_peak_speed(deg(t.rest), deg(to), PEAK_SPEED_DEG_S);
            t.command(roll_end_ns, to, m.duration_s);
            home_end_ns = home_end_ns.max(roll_end_ns + (m.duration_s * 1e9).ceil() as i64);
        }
        // the first frame a quarter second after the eyes reached home, on a whole millisecond
        let t0_ns = (home_end_ns + 250_000_000 + 999_999) / 1_000_000 * 1_000_000;
        let latency_ns = std::array::from_fn(|e| {
            let u = &head.units[e];
            (u.encoder_time_for_camera(0.0).abs() * 1e9).round() as i64
        });
        let max_latency = latency_ns.iter().copied().max().unwrap_or(0);
        let shared = Arc::new(Shared {
            board: Mutex::new(Board { traj, home, last_record_ns: None, done: None, pending_now: None, commands: 0 }),
            done: Condvar::new(),
            latency_ns,
            control_delay_ns: (CONTROL_DELAY_MS * 1e6) as i64 + max_latency,
        });
        let fks = [head.units[0].compile().map_err(inv)?, head.units[1].compile().map_err(inv)?];
        let streams = [fks[0].stream(), fks[1].stream()];
        let rays = RayTable::new(&head.camera).map_err(inv)?;
        let n = (spec.width * spec.height) as usize;
        let world_from_rhome = head.home_left_to_right.inverse();
        Ok(SimSource {
            shared,
            truth: Arc::default(),
            goals: Arc::default(),
            script: script.map(|s| s.goals.into()).unwrap_or_default(),
            fks,
            streams,
            rays,
            world_from_rhome,
            t0_ns,
            next: 0,
            left: vec![0; n],
            right: vec![0; n],
            board_taken: false,
            posted: 0,
            ended: None,
            head,
        })
    }

    /// The head's truth, for the sinks that score against it.
    pub fn truth(&self) -> Arc<TruthFeed> {
        self.truth.clone()
    }

    /// Where the script's goals go: set it to the runtime's gaze handle ([`abvs_runtime::Runtime::gaze`]).
    pub fn goal_slot(&self) -> GoalSlot {
        self.goals.clone()
    }

    /// The head.
    pub fn head(&self) -> &Head {
        &self.head
    }

    /// How long after a frame's last row the controller acts on it (ns).
    pub fn control_delay_ns(&self) -> i64 {
        self.shared.control_delay_ns
    }

    fn timing(&self, k: u64) -> (FrameTiming, i64) {
        let s = &self.head.spec;
        let (readout, exposure) = (s.readout_ms * 1e-3, s.exposure_ms * 1e-3);
        let t_frame_ns = self.t0_ns + (k as f64 * 1e9 / s.fps).round() as i64;
        let t_frame = (t_frame_ns - EPOCH_NS) as f64 * 1e-9;
        let t_start = t_frame - readout / 2.0 - exposure / 2.0;
        (FrameTiming { t_start, t_frame, readout, exposure, height: s.height }, t_frame_ns)
    }

    /// Waits until the gaze stage is done with frame `seq` (lockstep).
    fn wait_done(&self, seq: u64) -> bool {
        let mut b = self.shared.board.lock().expect("sim board");
        let deadline = std::time::Instant::now() + LOCKSTEP_TIMEOUT;
        while b.done.is_none_or(|d| d < seq) {
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            if left.is_zero() {
                return false;
            }
            b = self.shared.done.wait_timeout(b, left).expect("sim board").0;
        }
        true
    }

    /// Renders frame `k` into the source's buffers and records its truth.
    fn render(&mut self, k: u64) -> Result<()> {
        let (ft, t_frame_ns) = self.timing(k);
        let ns = |t: f64| EPOCH_NS + (t * 1e9).round() as i64;
        // a snapshot of the links' motion: the encoder feed may run while this frame renders
        let board = {
            let b = self.shared.board.lock().expect("sim board");
            Board {
                traj: b.traj.clone(),
                home: b.home,
                last_record_ns: None,
                done: None,
                pending_now: None,
                commands: 0,
            }
        };
        let angles = |e: usize, t: f64| Shared::theta(&board, e, ns(t));
        let th = [angles(0, ft.t_frame), angles(1, ft.t_frame)];
        // travel over the exposure window (rows' start of exposure to the last row's end)
        let span_end = ft.t_start + ft.readout + ft.exposure;
        let mut travel: f64 = 0.0;
        for e in 0..2 {
            let a = angles(e, ft.t_start);
            let mut t = ft.t_start;
            while t < span_end {
                t = (t + 0.5e-3).min(span_end);
                let b = angles(e, t);
                travel = travel.max((0..3).map(|i| (b[i] - a[i]).abs()).fold(0.0, f64::max));
            }
        }
        let s = &self.head.spec;
        let view = EyeView {
            scene: &self.head.scene,
            rays: &self.rays,
            camera: &self.head.camera,
            world_from_rhome: &self.world_from_rhome,
        };
        let g = [0.0, 1.0, 0.0];
        let mut world_from_cam = [Pose::identity(); 2];
        let mut left_rel = Pose::identity();
        let mut left_rows = Vec::with_capacity(TRUTH_ROW_NODES + 1);
        for e in 0..2 {
            let seed = s.seed * 1_000_003 + k * 2 + e as u64;
            let opts = crate::synth::eye_render_options(e, s.supersample, s.noise_sigma, seed, s.threads);
            let angles_at = |t: f64| Ok(angles(e, t));
            let img = view.render(e, &self.fks[e], &mut self.streams[e], &th[e], &angles_at, &ft, &opts)?;
            let buf = if e == 0 { &mut self.left } else { &mut self.right };
            buf.copy_from_slice(&img.gray);
            // the truth at the frame's instant, the motion history frozen at the frame (as the renderer holds it)
            let (cond, warm) = self.fks[e].peek(&self.streams[e], &th[e], g, None).map_err(inv)?;
            let (rel, _) = self.fks[e].pose_unchecked(&th[e], &cond, Some(&warm)).map_err(inv)?;
            let rel_m = Pose::new(rel.r, rel.t * 1e-3);
            world_from_cam[e] = if e == 0 { rel_m } else { self.world_from_rhome.compose(&rel_m) };
            if e == 0 {
                left_rel = rel_m;
                if ft.readout > 0.0 {
                    let mut warm = warm;
                    for n in 0..=TRUTH_ROW_NODES {
                        let t = ft.t_frame - ft.readout / 2.0 + n as f64 * ft.readout / TRUTH_ROW_NODES as f64;
                        let (q, r) = self.fks[0].pose_unchecked(&angles(0, t), &cond, Some(&warm)).map_err(inv)?;
                        warm = r;
                        left_rows.push(Pose::new(q.r, q.t * 1e-3));
                    }
                }
            }
        }
        self.truth.push(FrameTruth {
            seq: k,
            t_frame_ns,
            world_from_cam,
            left_rel,
            left_rows,
            theta_deg: th,
            travel_deg: travel,
        });
        Ok(())
    }

    /// Posts the script's goals due by frame `k`'s instant.
    fn post_goals(&mut self, t_frame_ns: i64) {
        let Some(h) = self.goals.get() else { return };
        while let Some(g) = self.script.front() {
            if self.t0_ns + (g.at_ms * 1e6).round() as i64 > t_frame_ns {
                break;
            }
            let g = self.script.pop_front().expect("just looked");
            g.post(h);
            self.posted += 1;
        }
    }
}

impl PairSource for SimSource {
    fn size(&self) -> (u32, u32) {
        (self.head.spec.width, self.head.spec.height)
    }

    fn start(&mut self, _now_ns: i64) -> Box<dyn EncoderFeed> {
        // virtual time: the run's clock is the head's, whatever the computer's
        Box::new(SimEncoders { shared: self.shared.clone(), next_ns: self.t0_ns - 200_000_000 })
    }

    fn board(&mut self) -> Option<Box<dyn BoardLink>> {
        if std::mem::replace(&mut self.board_taken, true) {
            return None;
        }
        Some(Box::new(SimBoardLink { shared: self.shared.clone() }))
    }

    fn next_frame(&mut self, limit: Option<u64>) -> Option<SourcePair<'_>> {
        let k = self.next;
        if limit.is_some_and(|n| k >= n) || self.ended.is_some() {
            return None;
        }
        // lockstep: frame k is drawn from every command the previous frames led to
        if k > 0 && self.board_taken && !self.wait_done(k - 1) {
            self.ended = Some(format!(
                "lockstep: the gaze stage did not finish frame {} within {} s",
                k - 1,
                LOCKSTEP_TIMEOUT.as_secs()
            ));
            return None;
        }
        let (ft, t_frame_ns) = self.timing(k);
        if let Err(e) = self.render(k) {
            self.ended = Some(format!("rendering frame {k}: {e}"));
            return None;
        }
        self.post_goals(t_frame_ns);
        self.next += 1;
        let t_start_ns = EPOCH_NS + (ft.t_start * 1e9).round() as i64;
        let s = &self.head.spec;
        Some(SourcePair {
            session_seq: k,
            seq: k,
            t_start_ns,
            right_t_start_ns: t_start_ns,
            exposure_ns: (s.exposure_ms * 1e6).round() as i64,
            readout_ns: (s.readout_ms * 1e6).round() as i64,
            readout_anchor: 0.0,
            left: &self.left,
            right: &self.right,
        })
    }

    fn finish(&mut self, stats: &mut RunStats) {
        let b = self.shared.board.lock().expect("sim board");
        stats.extra.insert(
            "sim".into(),
            serde_json::json!({
                "seed": self.head.spec.seed,
                "frames_rendered": self.next,
                "script_goals_posted": self.posted,
                "script_goals_left": self.script.len(),
                "board_commands": b.commands,
                "control_delay_ms": self.shared.control_delay_ns as f64 * 1e-6,
                "encoder_latency_ms": self.shared.latency_ns.map(|l| l as f64 * 1e-6),
            }),
        );
        if let Some(e) = &self.ended {
            stats.extra.insert("source_ended".into(), serde_json::json!(e));
        }
    }
}
