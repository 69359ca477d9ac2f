//! The runtime points the eyes, live, without a device: a simulated drive board (`abvs sim board --serve`,
//! a separate process executing move commands) on a pseudo-terminal, stand-in cameras delivering the
//! fixture's first pair in real time, and the standard graph with the gaze stage. A goal posted through the
//! gaze handle becomes command frames on the port the live source reads; the encoders then show the eyes at
//! the IK's counts, the measured fixation (encoders + calibrated FK) finds the point, and the frames exposed
//! during the saccade are gated.
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use abvs_board::stream::EncoderStream;
use abvs_camera::StereoCalibration;
use abvs_runtime::gaze::controller::GazeController;
use abvs_runtime::gaze::stage::GazeStage;
use abvs_runtime::gaze::{GazeConfig, GazeHandle, Mailbox};
use abvs_runtime::pipeline::{run_with_gaze, PipelineConfig};
use abvs_runtime::sources::live::LiveSource;
use abvs_runtime::sources::pairing::PairerConfig;
use abvs_runtime::sources::v4l_capture::StereoCapture;
use abvs_runtime::tasks::kinematics::{EyeFk, StereoKinematics};
use abvs_runtime_core::gaze::{GazeState, Phase};
use abvs_runtime_core::messages::monotonic_ns;
use abvs_runtime_core::messages::Published;
use abvs_runtime_core::messages::RectifiedCamera;
use abvs_runtime_core::sink::Sink;

mod common;
use common::*;

fn calib() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/session/calib")
}

/// Every published frame's gaze state.
struct States(Arc<Mutex<Vec<(GazeState, bool)>>>);

impl Sink for States {
    fn name(&self) -> &'static str {
        "gaze states"
    }
    fn consume(&mut self, out: &Published) -> abvs_runtime_core::error::Result<()> {
        self.0.lock().unwrap().push((out.motion.gaze, out.motion.gated));
        Ok(())
    }
}

#[test]
fn a_goal_moves_the_simulated_board_on_the_port_the_runtime_reads() {
    let t_test = std::time::Instant::now();
    let (master, slave) = serialport::TTYPort::pair().expect("pseudo-terminal pair");
    let name = serialport::SerialPort::name(&slave).expect("pty name");
    let mut master = master;
    serialport::SerialPort::set_timeout(&mut master, Duration::from_millis(50)).unwrap();
    // the live source's link: read the encoders, write the commands, one port
    let writer = master.try_clone_native().unwrap();
    let encoders = EncoderStream::spawn(master, name.clone(), 16_384).with_commands(Box::new(writer), name.clone());
    let mut board = Command::new(env!("CARGO_BIN_EXE_abvs"))
        .args(["sim", "board", "--port", &name, "--serve", "--seconds", "30", "--seed", "3"])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let t0 = std::time::Instant::now();
    while encoders.homed() != [true, true] {
        assert!(t0.elapsed() < Duration::from_secs(20), "not homed: {:?}", encoders.stats());
        std::thread::sleep(Duration::from_millis(10));
    }

    let fx = calib().join("..");
    let img = |eye: &str| -> (Vec<u8>, u32, u32) {
        let dir = fx.join("frames");
        let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
            .unwrap()
            .flatten()
            .map(|e| e.path())
            .filter(|p| p.file_name().unwrap().to_string_lossy().starts_with(eye))
            .collect();
        files.sort();
        let g = image::open(&files[0]).unwrap().to_luma8();
        let (w, h) = g.dimensions();
        (g.into_raw(), w, h)
    };
    let ((l, w, h), (r, _, _)) = (img("left"), img("right"));
    let n = 60;
    let t_first = monotonic_ns() + 100_000_000;
    let cam = |pixels| StillCamera { pixels, width: w, height: h, next: 0, n, t0: t_first };
    let capture = StereoCapture::from_sources(cam(l), cam(r), PairerConfig::default());
    let source = LiveSource::new(capture, encoders, w, h).with_readout_ns(READOUT_NS);

    let stereo = StereoCalibration::read_yaml(calib().join("stereo.yaml")).unwrap();
    let fk = |e: u32| EyeFk::load(&calib().join(format!("eye{e}"))).unwrap();
    let kin = StereoKinematics::new(fk(0), fk(1), stereo.rotation, stereo.translation_mm / 1000.0);
    let models = [kin.left.ik_model().unwrap(), kin.right.ik_model().unwrap()];
    let mailbox = Arc::new(Mailbox::default());
    let ctl = GazeController::new(GazeConfig::default(), models, &kin.home_left_to_right, kin.gravity);
    let stage = GazeStage::new(ctl, mailbox.clone(), kin.home_left_to_right);
    let out = RectifiedCamera::with_hfov(160, 120, 100.0);
    let max_disp = out.f * stereo.baseline_mm() / 1000.0 / 0.2;
    let engine = abvs_disparity::factory::engine("sgbm", None, (160, 120), max_disp, 1).unwrap();
    let states = Arc::new(Mutex::new(vec![]));
    let sinks: Vec<Box<dyn Sink>> = vec![Box::new(States(states.clone()))];
    let cfg = PipelineConfig { out, lossless: true, paced: false, frames: Some(n), ..Default::default() };
    let run = std::thread::spawn(move || {
        run_with_gaze(source, kin, (stereo.left, stereo.right), engine, sinks, cfg, Some(stage))
    });

    // after a few frames: both eyes to a point 0.6 m ahead, to the right and down
    let gaze = GazeHandle::new(mailbox);
    while gaze.state().is_none_or(|s| s.seq < 5) {
        assert!(!run.is_finished(), "the run ended early");
        std::thread::sleep(Duration::from_millis(5));
    }
    let p = [0.15, 0.1, 0.6];
    let id = gaze.look_at(p);
    let stats = run.join().unwrap().unwrap();
    let _ = board.kill();
    let board_err =
        board.wait_with_output().map(|o| String::from_utf8_lossy(&o.stderr).into_owned()).unwrap_or_default();
    let j = stats.json(1.0);
    let states = states.lock().unwrap();
    let phases: Vec<(u64, &str, bool)> = states.iter().map(|(s, g)| (s.goal_id, s.phase.name(), *g)).collect();
    eprintln!("{phases:?}\n{}\nboard: {board_err}", j["gaze"]);
    // (the board is killed: its summary line is not printed; the encoders below are the evidence)
    assert_eq!(j["gaze"]["accepted"], 1, "{j}");
    assert_eq!(j["gaze"]["commands"], 1, "one move command per eye: {j}");
    // idle, then the saccade, then settled for good
    assert_eq!(states[0].0.phase, Phase::Idle);
    let first = states.iter().position(|(s, _)| s.goal_id == id).expect("the goal was taken");
    assert_eq!(states[first].0.phase, Phase::Saccade, "{phases:?}");
    let settled = states.iter().position(|(s, _)| s.phase == Phase::Settled).expect("settled");
    assert!(states[settled..].iter().all(|(s, _)| s.phase == Phase::Settled && s.goal_id == id), "{phases:?}");
    // the encoders show the eyes where the IK put them: the optical axes meet at the point
    let last = states.last().unwrap().0;
    let err = (0..3).map(|i| (last.measured_m[i] - p[i]).powi(2)).sum::<f64>().sqrt();
    assert!(err < 0.005, "measured fixation {:?} vs {p:?}: {err} m", last.measured_m);
    assert!((last.vergence_m - 0.6).abs() < 0.1, "{}", last.vergence_m);
    // the saccade (about 30 ms with its margin) overlaps at least the next frame's 28 ms exposure: gated
    let gated = j["gaze"]["frames_gated_saccade"].as_u64().unwrap();
    assert!(gated >= 1, "{j}");
    assert_eq!(states.iter().filter(|(s, g)| s.gated_saccade && *g).count() as u64, gated);
    assert_eq!(stats.frames_published, n, "{j}");
    drop(slave);
    eprintln!("test wall time {:.1} s", t_test.elapsed().as_secs_f64());
}
