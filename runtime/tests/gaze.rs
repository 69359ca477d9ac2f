//! The gaze controller on the fixture calibration (hybrid FK models of two simulated eyes): goals become
//! yoked minimum-jerk moves of both eyes' calibrated IK; every bad goal is refused by name and sends
//! nothing; the mailbox keeps only the newest goal; a pursuit re-solves each frame; the measured fixation
//! (closest approach of the optical axes) finds the commanded point; frames exposed during a saccade are gated.
use std::path::Path;
use std::sync::Arc;

use abvs_camera::StereoCalibration;
use abvs_eye::encoder::counts_to_deg;
use abvs_eye::Pose;
use abvs_fk::model::FkModel;
use abvs_runtime::gaze::controller::GazeController;
use abvs_runtime::gaze::stage::measured_fixation;
use abvs_runtime::gaze::{GazeConfig, GazeHandle, Goal, GoalKind, Mailbox};
use abvs_runtime::tasks::kinematics::{moving_extrinsic, EyeFk};
use abvs_runtime_core::gaze::{Phase, Refusal};
use abvs_runtime_core::messages::StereoPose;
use abvs_runtime_core::source::BoardLink;

const NOW: i64 = 10_000_000_000;

/// The board as the controller sees it, recording the moves it is sent.
struct Board {
    homed: bool,
    last_ns: Option<i64>,
    sent: Vec<([[i64; 3]; 2], u32)>,
    /// The port refuses every write (a board unplugged after homing).
    fail: bool,
}

impl BoardLink for Board {
    fn home_counts(&self) -> Option<[[i64; 3]; 2]> {
        self.homed.then_some([[1000, 2000, 3000], [4000, 5000, 6000]])
    }
    fn last_record_ns(&self) -> Option<i64> {
        self.last_ns
    }
    fn send_move(&mut self, target_counts: [[i64; 3]; 2], duration_us: u32) -> Result<(), String> {
        if self.fail {
            return Err("writing to the board: broken pipe".into());
        }
        self.sent.push((target_counts, duration_us));
        Ok(())
    }
}

fn live_board() -> Board {
    Board { homed: true, last_ns: Some(NOW - 1_000_000), sent: vec![], fail: false }
}

fn calib() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/session/calib")
}

fn home_extrinsic_m() -> Pose {
    let s = StereoCalibration::read_yaml(calib().join("stereo.yaml")).unwrap();
    Pose::new(s.rotation, s.translation_mm / 1000.0)
}

fn controller() -> GazeController {
    let models = [0, 1].map(|e| FkModel::load(&calib().join(format!("eye{e}"))).unwrap());
    GazeController::new(GazeConfig::default(), models, &home_extrinsic_m(), [0.0, 1.0, 0.0])
}

fn goal(id: u64, kind: GoalKind, p: [f64; 3], v: [f64; 3]) -> Goal {
    Goal { id, kind, point_m: p, velocity_m_s: v }
}

#[test]
fn every_bad_goal_is_refused_by_name_and_nothing_moves() {
    let t = std::time::Instant::now();
    let mut c = controller();
    let th = [[0.0; 3]; 2];
    let cases: [(Goal, Refusal); 6] = [
        (goal(1, GoalKind::LookAt, [f64::NAN, 0.0, 1.0], [0.0; 3]), Refusal::NonFinite),
        (goal(2, GoalKind::Pursue, [0.0, 0.0, 1.0], [f64::INFINITY, 0.0, 0.0]), Refusal::NonFinite),
        (goal(3, GoalKind::LookAt, [0.0, 0.0, -1.0], [0.0; 3]), Refusal::BehindEyes),
        (goal(4, GoalKind::LookAt, [0.0, 0.0, 0.05], [0.0; 3]), Refusal::TooNear),
        (goal(5, GoalKind::LookAt, [2.0, 0.0, 0.5], [0.0; 3]), Refusal::OutsideWorkspace),
        (goal(6, GoalKind::LookAt, [0.0, 0.9, 0.6], [0.0; 3]), Refusal::OutsideWorkspace),
    ];
    let mut board = live_board();
    for (g, why) in cases {
        c.step(NOW, &th, Some(g), Some(&mut board));
        let s = c.state(7);
        assert_eq!((s.goal_id, s.phase, s.reason), (g.id, Phase::Refused, Some(why)), "{g:?}");
        assert!(s.commanded_m.iter().all(|v| v.is_nan()));
    }
    // the board's state refuses a good point: not homed, silent encoders, no board at all
    let good = goal(10, GoalKind::LookAt, [0.05, -0.02, 0.6], [0.0; 3]);
    let mut unhomed = Board { homed: false, ..live_board() };
    c.step(NOW, &th, Some(good), Some(&mut unhomed));
    assert_eq!(c.state(0).reason, Some(Refusal::NotHomed));
    let mut silent = Board { last_ns: Some(NOW - 500_000_000), ..live_board() };
    c.step(NOW, &th, Some(good), Some(&mut silent));
    assert_eq!(c.state(0).reason, Some(Refusal::EncodersSilent));
    let mut never = Board { last_ns: None, ..live_board() };
    c.step(NOW, &th, Some(good), Some(&mut never));
    assert_eq!(c.state(0).reason, Some(Refusal::EncodersSilent));
    c.step(NOW, &th, Some(good), None);
    assert_eq!(c.state(0).reason, Some(Refusal::NoBoard));
    // a write that fails is refused by name: the goal is not taken as under way
    let mut broken = Board { fail: true, ..live_board() };
    c.step(NOW, &th, Some(good), Some(&mut broken));
    let s = c.state(0);
    assert_eq!((s.phase, s.reason), (Phase::Refused, Some(Refusal::SendFailed)));
    assert!(s.commanded_m.iter().all(|v| v.is_nan()) && s.planned_ms == 0.0);
    assert!(!c.overlaps_saccade(NOW - 50_000_000, NOW + 50_000_000), "no saccade gates frames after a failed send");
    assert!(board.sent.is_empty() && unhomed.sent.is_empty() && silent.sent.is_empty() && never.sent.is_empty());
    let j = c.counts.json();
    assert_eq!(j["goals"], 11);
    assert_eq!(j["accepted"], 0);
    for (name, n) in [
        ("non_finite", 2),
        ("behind_eyes", 1),
        ("too_near", 1),
        ("outside_workspace", 2),
        ("not_homed", 1),
        ("encoders_silent", 2),
        ("no_board", 1),
        ("send_failed", 1),
        ("near_singular", 0),
    ] {
        assert_eq!(j["refused"][name], n, "{name}: {j}");
    }
    // the same good point with a live board is accepted
    c.step(NOW, &th, Some(good), Some(&mut board));
    assert_eq!(c.state(0).phase, Phase::Saccade);
    assert_eq!(board.sent.len(), 1);
    println!("refusals: {:.2} s", t.elapsed().as_secs_f64());
}

#[test]
fn a_goal_becomes_a_yoked_saccade_that_settles_and_gates_its_frames() {
    let mut c = controller();
    let mut board = live_board();
    let th = [[0.0; 3]; 2];
    let p = [0.08, -0.05, 0.7];
    c.step(NOW, &th, Some(goal(42, GoalKind::LookAt, p, [0.0; 3])), Some(&mut board));
    let s = c.state(1);
    assert_eq!((s.goal_id, s.phase, s.reason), (42, Phase::Saccade, None));
    assert_eq!(s.commanded_m, p);
    let (counts, dur_us) = board.sent[0];
    // both eyes' link angles reached by the plan, at the peak speed: duration = 15/8 travel / 1561 deg/s
    let to = counts.map(|c| c.map(|x| counts_to_deg(x, 0)));
    let travel = to.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(travel > 1.0, "{to:?}");
    let want_us = 1.875 * travel / 1561.0 * 1e6;
    assert!((dur_us as f64 - want_us).abs() <= 1.0, "{dur_us} vs {want_us}");
    assert!((s.planned_ms - dur_us as f64 * 1e-3).abs() < 1e-9);
    // frames whose exposure overlaps [send, end + margin] are gated; those before or after are not
    let end = NOW + dur_us as i64 * 1000;
    assert!(c.overlaps_saccade(NOW - 5_000_000, NOW + 1));
    assert!(c.overlaps_saccade(end + 4_000_000, end + 9_000_000));
    assert!(!c.overlaps_saccade(NOW - 20_000_000, NOW - 1));
    assert!(!c.overlaps_saccade(end + 5_000_001, end + 20_000_000));
    // still moving at the end of the plan: not settled until the encoders read the target
    c.step(end + 1, &th, None, Some(&mut board));
    assert_eq!(c.state(2).phase, Phase::Saccade);
    c.step(end + 2, &to, None, Some(&mut board));
    assert_eq!(c.state(3).phase, Phase::Settled);
    assert_eq!(c.counts.settled, 1);
    assert_eq!(board.sent.len(), 1, "a settled look_at sends nothing more");
    // home: all links to 0 counts
    c.step(end + 3, &to, Some(goal(43, GoalKind::Home, [0.0; 3], [0.0; 3])), Some(&mut board));
    assert_eq!(board.sent[1].0, [[0; 3]; 2]);
    assert!(c.state(4).commanded_m[0].is_nan());
}

#[test]
fn the_measured_fixation_finds_the_commanded_point() {
    let mut board = live_board();
    let h = home_extrinsic_m();
    for p in [[0.0, 0.0, 0.5], [0.1, -0.05, 0.8], [-0.2, 0.1, 1.5]] {
        // each from home, as the runtime's FK below evaluates it (the same motion history)
        let mut c = controller();
        c.step(NOW, &[[0.0; 3]; 2], Some(goal(1, GoalKind::LookAt, p, [0.0; 3])), Some(&mut board));
        let counts = board.sent.last().unwrap().0;
        // the poses the runtime's FK gives at those link angles (the same calibrated models)
        let rel = [0, 1].map(|e| {
            let mut fk = EyeFk::load(&calib().join(format!("eye{e}"))).unwrap();
            // the controller's history: a reading at home, then the move (backlash depends on the approach)
            fk.pose(&[0.0; 3], [0.0, 1.0, 0.0]).unwrap();
            fk.pose(&counts[e].map(|x| counts_to_deg(x, 0)), [0.0, 1.0, 0.0]).unwrap()
        });
        let pose =
            StereoPose { rel_left: rel[0], rel_right: rel[1], left_to_right: moving_extrinsic(&rel[0], &rel[1], &h) };
        let (m, verg) = measured_fixation(&pose, &h);
        let err = ((m[0] - p[0]).powi(2) + (m[1] - p[1]).powi(2) + (m[2] - p[2]).powi(2)).sqrt();
        // whole encoder counts: 0.0039 deg of each axis, ~ a millimetre of depth at 1.5 m
        assert!(err < 0.003 * p[2] * p[2], "{p:?}: measured {m:?} ({err} m)");
        assert!((verg - (p[0].powi(2) + p[1].powi(2) + p[2].powi(2)).sqrt()).abs() < 0.05, "{verg}");
    }
    // parallel axes: no fixation
    let id = Pose::identity();
    let parallel = Pose::new(nalgebra::Matrix3::identity(), h.t);
    let pose = StereoPose { rel_left: id, rel_right: id, left_to_right: parallel };
    assert!(measured_fixation(&pose, &parallel).1.is_nan());
}

#[test]
fn a_pursuit_re_solves_every_frame_and_a_refusal_stops_it() {
    let mut c = controller();
    let mut board = live_board();
    let v = [0.2, 0.0, 0.0];
    let mut th = [[0.0; 3]; 2];
    c.step(NOW, &th, Some(goal(7, GoalKind::Pursue, [-0.1, 0.0, 0.8], v)), Some(&mut board));
    assert_eq!(c.state(0).phase, Phase::Pursuit);
    let mut last_yaw = f64::NEG_INFINITY;
    for k in 1..=5 {
        let now = NOW + k * 33_000_000;
        let mut b = Board { last_ns: Some(now - 1_000_000), ..live_board() };
        c.step(now, &th, None, Some(&mut b));
        let s = c.state(k as u64);
        assert_eq!((s.phase, s.goal_id), (Phase::Pursuit, 7));
        assert!((s.commanded_m[0] - (-0.1 + 0.2 * k as f64 * 0.033)).abs() < 1e-9, "{:?}", s.commanded_m);
        assert_eq!(b.sent.len(), 1, "one move per frame");
        let (counts, dur) = b.sent[0];
        assert!((dur as i64 - 33_000).abs() <= 1, "{dur}");
        th = counts.map(|c| c.map(|x| counts_to_deg(x, 0)));
        // the point moves right: the links' mean (yaw, roughly) moves one way only
        let yaw: f64 = th[0].iter().sum();
        assert!(yaw != last_yaw);
        last_yaw = yaw;
    }
    // the encoders fall silent: the pursuit stops, refused by name, nothing sent
    let now = NOW + 6 * 33_000_000;
    let mut b = Board { last_ns: Some(now - 300_000_000), ..live_board() };
    c.step(now, &th, None, Some(&mut b));
    assert_eq!(c.state(6).reason, Some(Refusal::EncodersSilent));
    c.step(now + 33_000_000, &th, None, Some(&mut live_board()));
    assert_eq!(c.state(7).phase, Phase::Refused, "a refused pursuit does not resume by itself");
    assert!(b.sent.is_empty());
}

#[test]
fn a_flood_of_goals_keeps_only_the_newest() {
    let mailbox = Arc::new(Mailbox::default());
    let h = GazeHandle::new(mailbox.clone());
    let ids: Vec<u64> = (0..10_000).map(|k| h.look_at([0.0, 0.0, 0.5 + k as f64 * 1e-5])).collect();
    assert!(ids.windows(2).all(|w| w[1] == w[0] + 1) && ids[0] > 0);
    let g = mailbox.take().unwrap();
    assert_eq!(g.id, *ids.last().unwrap());
    assert!(mailbox.take().is_none());
    assert_eq!(mailbox.counts(), (10_000, 9_999));
    let p = h.pursue([0.0, 0.0, 1.0], [0.1, 0.0, 0.0]);
    let g = mailbox.take().unwrap();
    assert_eq!((g.id, g.kind, g.velocity_m_s), (p, GoalKind::Pursue, [0.1, 0.0, 0.0]));
    assert_eq!(mailbox.take(), None);
    assert_eq!(h.hold(), p + 1);
    assert_eq!(mailbox.take().unwrap().kind, GoalKind::Hold);
}
