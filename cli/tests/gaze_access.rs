//! Who may move the eyes (docs/gaze.md): gaze goals over Zenoh against a live head without a device, as in
//! `gaze_live.rs` (the simulated drive board, `abvs sim board --serve`, on a pseudo-terminal; stand-in
//! cameras at 25 fps; the standard graph with the gaze stage), with the runtime's Zenoh gaze topics
//! (`bridges::zenoh_gaze`) on loopback and real Zenoh peers in this process.
//!
//! - With the shipped access control (`config/zenoh-gaze-acl.json5`, the file docs/gaze.md shows): a logged-in
//!   peer that is not the commander sends goals and the eyes do not move (Zenoh's access control drops them
//!   before the runtime: nothing is posted, no command is sent), a peer without credentials cannot connect,
//!   and then the commander's goal moves the board and the encoders put the fixation on its point.
//! - A flood of goals (10 kHz for 1 s) against a run without it, paired: the frames published and the run's
//!   pace unchanged, the process's memory flat, and the commands sent to the board within the rate limit.
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use abvs_board::stream::EncoderStream;
use abvs_camera::StereoCalibration;
use abvs_runtime::bridges::zenoh_gaze::{self, ZenohGaze};
use abvs_runtime::gaze::controller::GazeController;
use abvs_runtime::gaze::stage::GazeStage;
use abvs_runtime::gaze::{GazeConfig, GazeHandle, Mailbox};
use abvs_runtime::pipeline::{run_with_gaze, PipelineConfig};
use abvs_runtime::sources::live::LiveSource;
use abvs_runtime::sources::pairing::PairerConfig;
use abvs_runtime::sources::v4l_capture::StereoCapture;
use abvs_runtime::tasks::kinematics::{EyeFk, StereoKinematics};
use abvs_runtime_core::config::ZenohSettings;
use abvs_runtime_core::messages::monotonic_ns;
use abvs_runtime_core::messages::RectifiedCamera;
use abvs_runtime_core::params::RateLimit;
use abvs_runtime_core::sink::Sink;
use abvs_runtime_core::stats::RunStats;
use zenoh::Wait;

mod common;
use common::*;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn calib() -> PathBuf {
    repo().join("fixtures/session/calib")
}

/// One live head at a time: the paired flood runs must not share the two cores with another.
static ONE_HEAD: Mutex<()> = Mutex::new(());

/// A running live head: the pipeline's thread, its gaze handle, and the simulated board.
struct Head {
    run: JoinHandle<abvs_runtime_core::error::Result<RunStats>>,
    gaze: GazeHandle,
    board: Child,
    _slave: serialport::TTYPort,
}

impl Head {
    /// The board homed, then `n` frames through the standard graph with `sink`; goals through `mailbox`.
    fn start(n: u64, limit: RateLimit, mailbox: Arc<Mailbox>, sink: Box<dyn Sink>) -> Head {
        let (master, slave) = serialport::TTYPort::pair().expect("pseudo-terminal pair");
        let name = serialport::SerialPort::name(&slave).expect("pty name");
        let mut master = master;
        serialport::SerialPort::set_timeout(&mut master, Duration::from_millis(50)).unwrap();
        let writer = master.try_clone_native().unwrap();
        let encoders = EncoderStream::spawn(master, name.clone(), 16_384).with_commands(Box::new(writer), name.clone());
        let board = Command::new(env!("CARGO_BIN_EXE_abvs"))
            .args(["sim", "board", "--port", &name, "--serve", "--seconds", "30", "--seed", "3"])
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        let t0 = Instant::now();
        while encoders.homed() != [true, true] {
            assert!(t0.elapsed() < Duration::from_secs(20), "not homed: {:?}", encoders.stats());
            std::thread::sleep(Duration::from_millis(10));
        }
        let img = |eye: &str| -> (Vec<u8>, u32, u32) {
            let dir = repo().join("fixtures/session/frames");
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
        let t_first = monotonic_ns() + 100_000_000;
        let cam = |pixels| StillCamera { pixels, width: w, height: h, next: 0, n, t0: t_first };
        let capture = StereoCapture::from_sources(cam(l), cam(r), PairerConfig::default());
        let source = LiveSource::new(capture, encoders, w, h).with_readout_ns(READOUT_NS);
        let stereo = StereoCalibration::read_yaml(calib().join("stereo.yaml")).unwrap();
        let fk = |e: u32| EyeFk::load(&calib().join(format!("eye{e}"))).unwrap();
        let kin = StereoKinematics::new(fk(0), fk(1), stereo.rotation, stereo.translation_mm / 1000.0);
        let models = [kin.left.ik_model().unwrap(), kin.right.ik_model().unwrap()];
        let ctl = GazeController::new(GazeConfig::default(), models, &kin.home_left_to_right, kin.gravity);
        let stage = GazeStage::new(ctl, mailbox.clone(), kin.home_left_to_right).with_rate_limit(limit);
        let out = RectifiedCamera::with_hfov(160, 120, 100.0);
        let max_disp = out.f * stereo.baseline_mm() / 1000.0 / 0.2;
        let engine = abvs_disparity::factory::engine("sgbm", None, (160, 120), max_disp, 1).unwrap();
        // live: a frame the pipeline cannot keep up with is dropped (counted), as on the robot
        let cfg = PipelineConfig { out, lossless: false, paced: false, frames: Some(n), ..Default::default() };
        let run = std::thread::spawn(move || {
            run_with_gaze(source, kin, (stereo.left, stereo.right), engine, vec![sink], cfg, Some(stage))
        });
        Head { run, gaze: GazeHandle::new(mailbox), board, _slave: slave }
    }

    /// Waits until the frame `seq` has been processed.
    fn until_frame(&self, seq: u64) {
        let t = Instant::now();
        while self.gaze.state().is_none_or(|s| s.seq < seq) {
            assert!(!self.run.is_finished(), "the run ended early");
            assert!(t.elapsed() < Duration::from_secs(30), "frame {seq} never came");
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    fn finish(mut self) -> serde_json::Value {
        let stats = self.run.join().unwrap().unwrap();
        let _ = self.board.kill();
        let _ = self.board.wait();
        let mut j = stats.json(1.0);
        j["frames_published"] = serde_json::json!(stats.frames_published);
        j
    }
}

fn free_endpoint() -> String {
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    format!("tcp/127.0.0.1:{}", l.local_addr().unwrap().port())
}

/// A Zenoh client of the runtime's session at `endpoint`, logged in as `user` (None: no credentials).
fn peer(endpoint: &str, user: Option<(&str, &str)>) -> zenoh::Result<zenoh::Session> {
    let mut c = zenoh::Config::default();
    c.insert_json5("mode", "\"client\"")?;
    c.insert_json5("connect/endpoints", &serde_json::to_string(&[endpoint]).unwrap())?;
    c.insert_json5("scouting/multicast/enabled", "false")?;
    if let Some((u, p)) = user {
        c.insert_json5("transport/auth/usrpwd/user", &serde_json::to_string(u).unwrap())?;
        c.insert_json5("transport/auth/usrpwd/password", &serde_json::to_string(p).unwrap())?;
    }
    zenoh::open(c).wait()
}

/// A geometry_msgs/msg/PointStamped in the left home camera frame, as CDR.
fn point_stamped(p: [f64; 3]) -> Vec<u8> {
    let frame = b"left_home_camera";
    let mut b = vec![0u8, 1, 0, 0];
    b.extend_from_slice(&0i32.to_le_bytes());
    b.extend_from_slice(&0u32.to_le_bytes());
    b.extend_from_slice(&(frame.len() as u32 + 1).to_le_bytes());
    b.extend_from_slice(frame);
    b.push(0);
    while (b.len() - 4) % 8 != 0 {
        b.push(0);
    }
    for v in p {
        b.extend_from_slice(&v.to_le_bytes());
    }
    b
}

/// The gaze topics of a runtime taking goals, listening on `endpoint`, with `config` (a Zenoh file) or none
/// (insecure); and the start-up line.
fn zenoh_gaze(endpoint: &str, config: Option<PathBuf>, mailbox: Arc<Mailbox>) -> (Box<dyn Sink>, String) {
    let settings = ZenohSettings {
        listen: vec![endpoint.to_string()],
        accept_gaze_goals: true,
        insecure: config.is_none(),
        config,
        ..Default::default()
    };
    let zc = zenoh_gaze::config(&settings).unwrap();
    let line = zenoh_gaze::goal_access(&settings, &zc, false).unwrap();
    let session = zenoh::open(zc).wait().unwrap();
    (Box::new(ZenohGaze::new(session, &settings, mailbox, false).unwrap()), line)
}

/// Samples of the state topic a session receives.
fn count_states(s: &zenoh::Session) -> (Arc<std::sync::atomic::AtomicU64>, zenoh::pubsub::Subscriber<()>) {
    let n = Arc::new(std::sync::atomic::AtomicU64::new(0));
    let c = n.clone();
    let sub = s
        .declare_subscriber("abvs/gaze/state")
        .callback(move |_| {
            c.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        })
        .wait()
        .unwrap();
    (n, sub)
}

#[test]
fn only_the_commander_moves_the_eyes_under_the_shipped_access_control() {
    let _one = ONE_HEAD.lock().unwrap_or_else(|e| e.into_inner());
    let t_test = Instant::now();
    let acl = repo().join("config/zenoh-gaze-acl.json5");
    let endpoint = free_endpoint();
    let mailbox = Arc::new(Mailbox::default());
    let (sink, line) = zenoh_gaze(&endpoint, Some(acl), mailbox.clone());
    eprintln!("{line}");
    assert!(line.contains("authenticated peers (user/password)") && line.contains("deny by default"), "{line}");
    let head = Head::start(75, RateLimit::default(), mailbox, sink);

    // the users of config/zenoh-users.txt; a peer without credentials is not let in
    let viewer = peer(&endpoint, Some(("viewer", "change-me-viewer"))).expect("the viewer logs in");
    let commander = peer(&endpoint, Some(("commander", "change-me-commander"))).expect("the commander logs in");
    let stranger = peer(&endpoint, None);
    let (viewer_states, _vs) = count_states(&viewer);
    let stranger_states = stranger.as_ref().ok().map(count_states);

    head.until_frame(10);
    // the viewer receives the runtime's state (its link is up)...
    assert!(viewer_states.load(std::sync::atomic::Ordering::Relaxed) > 0, "the viewer sees no state");
    // ...but its goals, and the stranger's, never reach the controller: the eyes do not move
    let p_bad = [-0.15, 0.05, 0.5];
    for _ in 0..10 {
        viewer.put("abvs/gaze/goal", point_stamped(p_bad)).wait().unwrap();
        if let Ok(s) = &stranger {
            let _ = s.put("abvs/gaze/goal", point_stamped(p_bad)).wait();
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let seq = head.gaze.state().unwrap().seq;
    head.until_frame(seq + 8);
    let st = head.gaze.state().unwrap();
    assert_eq!((st.goal_id, st.phase.name()), (0, "idle"), "a denied goal was taken: {st:?}");
    if let Some((n, _)) = &stranger_states {
        assert_eq!(n.load(std::sync::atomic::Ordering::Relaxed), 0, "a peer without credentials got in");
    }

    // the commander's goal moves the eyes: the same topic, the same link, another user
    let p = [0.15, 0.1, 0.6];
    commander.put("abvs/gaze/goal", point_stamped(p)).wait().unwrap();
    let j = head.finish();
    let g = &j["gaze"];
    eprintln!("{g}\n{}", j["gaze_zenoh"]);
    assert_eq!(g["sources"]["zenoh"]["posted"], 1, "only the commander's goal arrived: {g}");
    assert_eq!(j["gaze_zenoh"]["goals_received"], 1, "{j}");
    assert_eq!((g["accepted"].as_u64(), g["commands"].as_u64()), (Some(1), Some(1)), "{g}");
    assert_eq!(g["sources"]["zenoh"]["taken"], 1, "{g}");
    assert_eq!(g["sources"]["zenoh"]["refused"], 0, "{g}");
    drop((viewer, commander, stranger));
    eprintln!("test wall time {:.1} s", t_test.elapsed().as_secs_f64());
}

/// Resident memory of this process (bytes).
fn rss() -> u64 {
    let s = std::fs::read_to_string("/proc/self/statm").unwrap();
    s.split_whitespace().nth(1).unwrap().parse::<u64>().unwrap() * 4096
}

#[test]
fn a_flood_of_goals_keeps_the_frame_rate_and_the_rate_limit() {
    let _one = ONE_HEAD.lock().unwrap_or_else(|e| e.into_inner());
    let t_test = Instant::now();
    // a limit well under the frame rate (25 fps): the frames alone would let 25 goals a second through
    let limit = RateLimit { max_goals_per_s: 5.0, goal_burst: 2 };
    let n = 60;
    let mut runs = Vec::new();
    for flood in [false, true] {
        let endpoint = free_endpoint();
        let mailbox = Arc::new(Mailbox::default());
        let (sink, _) = zenoh_gaze(&endpoint, None, mailbox.clone());
        let head = Head::start(n, limit, mailbox, sink);
        let sender = peer(&endpoint, None).unwrap();
        let publisher = sender.declare_publisher("abvs/gaze/goal").wait().unwrap();
        head.until_frame(10);
        let (mut sent, mut flood_s, rss0) = (0u64, 0.0, rss());
        let mut rss_max = rss0;
        let goals = [point_stamped([0.15, 0.1, 0.6]), point_stamped([-0.1, 0.0, 0.8])];
        if flood {
            // 10 kHz for 1 s, alternating between two points: every goal executed is a move
            let t0 = Instant::now();
            while t0.elapsed() < Duration::from_secs(1) {
                let due = (t0.elapsed().as_secs_f64() * 10_000.0) as u64;
                while sent < due {
                    publisher.put(goals[(sent % 2) as usize].clone()).wait().unwrap();
                    sent += 1;
                }
                if sent % 1000 == 0 {
                    rss_max = rss_max.max(rss());
                }
                std::thread::sleep(Duration::from_micros(50));
            }
            flood_s = t0.elapsed().as_secs_f64();
        }
        rss_max = rss_max.max(rss());
        let mut j = head.finish();
        j["sent"] = serde_json::json!(sent);
        j["flood_s"] = serde_json::json!(flood_s);
        j["rss_growth_mb"] = serde_json::json!((rss_max.saturating_sub(rss0)) as f64 / 1e6);
        eprintln!(
            "flood {flood}: sent {sent} in {flood_s:.2} s, published {}, elapsed {}, gaze {}, zenoh {}, rss +{} MB",
            j["frames_published"], j["elapsed_s"], j["gaze"], j["gaze_zenoh"], j["rss_growth_mb"]
        );
        runs.push(j);
    }
    let (base, flood) = (&runs[0], &runs[1]);
    let sent = flood["sent"].as_u64().unwrap();
    assert!(sent >= 9_000, "the flood: {sent} goals");
    let received = flood["gaze_zenoh"]["goals_received"].as_u64().unwrap();
    assert!(received >= sent / 2, "the flood reached the runtime: {received} of {sent}");
    // the pipeline kept its frame rate: the same frames published, at the same pace (paired)
    let published = |j: &serde_json::Value| j["frames_published"].as_u64().unwrap();
    assert!(published(flood) + 1 >= published(base) && published(base) >= n - 2, "{base}\n{flood}");
    let pace = flood["elapsed_s"].as_f64().unwrap() / base["elapsed_s"].as_f64().unwrap();
    assert!(pace < 1.05, "the flood slowed the run: x{pace:.3}");
    // memory bounded: the mailbox holds one goal, the gate one more
    let growth = flood["rss_growth_mb"].as_f64().unwrap();
    assert!(growth < 32.0, "memory grew by {growth} MB during the flood");
    // the eyes executed at most the rate limit: commands sent to the board (one per executed look_at; the
    // goal waiting when the flood ends goes once more)
    let commands = flood["gaze"]["commands"].as_u64().unwrap();
    let most = limit.most_in(flood["flood_s"].as_f64().unwrap()) + 1;
    assert!(commands <= most && commands >= 3, "commands {commands}, limit {most}: {}", flood["gaze"]);
    let z = &flood["gaze"]["sources"]["zenoh"];
    assert!(z["rate_limited"].as_u64().unwrap() > 0, "{z}");
    assert_eq!(z["posted"].as_u64().unwrap(), received, "{z}");
    assert_eq!(base["gaze"]["commands"], 0);
    eprintln!("test wall time {:.1} s", t_test.elapsed().as_secs_f64());
}
