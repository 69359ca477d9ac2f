//! The generic runner takes new sinks and side stages from the outside: a test sink and two side stages
//! (one appended to an existing lane, one on a lane of its own) join the standard graph without any change
//! to the runner, see every frame, and leave the published depth unchanged. Descriptions that do not name
//! the stages given, or put the depth stage before the output lane, are refused with the reason.
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use abvs_camera::StereoCalibration;
use abvs_disparity::factory as disparity;
use abvs_runtime::pipeline;
use abvs_runtime::pipeline::PipelineConfig;
use abvs_runtime::runner;
use abvs_runtime::runner::{Graph, Lane};
use abvs_runtime::sources::replay::ReplaySource;
use abvs_runtime::tasks::depth::{DepthConfig, DepthStage};
use abvs_runtime::tasks::kinematics::{EyeFk, StereoKinematics};
use abvs_runtime_core::messages::Published;
use abvs_runtime_core::messages::Work;
use abvs_runtime_core::session::Session;
use abvs_runtime_core::sink::Sink;
use abvs_runtime_core::stage::{Stage, StageContext};
use abvs_runtime_core::stats::RunStats;

const FRAMES: u64 = 20;

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/session")
}

fn cfg() -> PipelineConfig {
    PipelineConfig { lossless: true, paced: false, frames: Some(FRAMES), ..Default::default() }
}

/// The standard graph over the fixture session with SGBM and no sinks.
fn standard() -> Graph<ReplaySource> {
    let session = Session::open(&fixture()).unwrap();
    let stereo = StereoCalibration::read_yaml(session.path(&session.meta.stereo)).unwrap();
    let kin = StereoKinematics::new(
        EyeFk::load(&session.path(&session.meta.fk[0])).unwrap(),
        EyeFk::load(&session.path(&session.meta.fk[1])).unwrap(),
        stereo.rotation,
        stereo.translation_mm / 1000.0,
    );
    let c = cfg();
    let eng = disparity::engine("sgbm", None, (c.out.width, c.out.height), 48.0, 2).unwrap();
    let source = ReplaySource::open(session).unwrap();
    pipeline::graph(source, kin, (stereo.left, stereo.right), eng, Vec::new(), &c).unwrap()
}

/// A side stage: the mean gray level of each rectified left image it sees, by frame seq.
struct Brightness {
    name: &'static str,
    seen: Arc<Mutex<Vec<(u64, f64)>>>,
    started: bool,
}

impl Stage for Brightness {
    fn name(&self) -> &'static str {
        self.name
    }
    fn start(&mut self, ctx: &mut StageContext) -> abvs_runtime_core::error::Result<()> {
        assert_eq!((ctx.out.width, ctx.out.height), (320, 240));
        self.started = true;
        Ok(())
    }
    fn process(&mut self, w: &mut Work) -> abvs_runtime_core::error::Result<()> {
        assert!(self.started && w.rectified.rect.is_some(), "runs after rectification");
        let l = &w.rectified.left;
        let mean = l.iter().map(|&v| v as f64).sum::<f64>() / l.len() as f64;
        self.seen.lock().unwrap().push((w.seq, mean));
        Ok(())
    }
    fn finish(&mut self, stats: &mut RunStats) {
        stats.extra.insert(format!("{}_frames", self.name), serde_json::json!(self.seen.lock().unwrap().len()));
    }
}

/// A sink recording the seq and point count of every published frame.
struct Recorder(Arc<Mutex<Vec<(u64, usize)>>>);

impl Sink for Recorder {
    fn name(&self) -> &'static str {
        "recorder"
    }
    fn consume(&mut self, out: &Published) -> abvs_runtime_core::error::Result<()> {
        self.0.lock().unwrap().push((out.seq, out.depth.n_points));
        Ok(())
    }
}

/// A sink that fails on every frame (a full disk under --dump).
struct Failing;

impl Sink for Failing {
    fn name(&self) -> &'static str {
        "failing"
    }
    fn consume(&mut self, _: &Published) -> abvs_runtime_core::error::Result<()> {
        Err(abvs_runtime_core::error::RuntimeError::Invalid("disk full".into()))
    }
}

#[test]
fn a_sink_and_side_stages_join_the_graph_without_touching_the_runner() {
    let plain = runner::run(standard(), &cfg().run_config()).unwrap();
    assert_eq!(plain.frames_published, FRAMES);

    let mut g = standard();
    let (in_lane, own_lane, sunk) = (Arc::default(), Arc::default(), Arc::default());
    // appended to the rectify lane (same thread as rectification)
    let side = Brightness { name: "brightness", seen: Arc::clone(&in_lane), started: false };
    g.add_stage("rectify", Box::new(side)).unwrap();
    // on a lane (thread) of its own, between disparity and the output
    let own = Brightness { name: "brightness_lane", seen: Arc::clone(&own_lane), started: false };
    let at = g.lanes.len() - 1;
    g.lanes.insert(at, Lane { name: "check", stages: vec![Box::new(own)] });
    g.add_sink(Box::new(Failing));
    g.add_sink(Box::new(Recorder(Arc::clone(&sunk))));
    assert_eq!(g.stage_names(), ["source", "rectify", "disparity", "check", "output"]);
    let stats = runner::run(g, &cfg().run_config()).unwrap();

    // every frame went through both side stages and reached the sink, in order
    let seqs = |v: &[(u64, f64)]| v.iter().map(|x| x.0).collect::<Vec<_>>();
    let sunk = sunk.lock().unwrap();
    let published: Vec<u64> = sunk.iter().map(|x| x.0).collect();
    assert_eq!(published.len() as u64, FRAMES);
    assert_eq!(seqs(&in_lane.lock().unwrap()), published);
    assert_eq!(seqs(&own_lane.lock().unwrap()), published);
    assert_eq!(*in_lane.lock().unwrap(), *own_lane.lock().unwrap(), "both saw the same rectified images");
    assert!(sunk.iter().all(|x| x.1 > 1000), "frames carry depth");
    // their statistics: the side stages' counts, the new lane's latency histogram
    assert_eq!(stats.extra["brightness_frames"], serde_json::json!(FRAMES));
    assert_eq!(stats.extra["brightness_lane_frames"], serde_json::json!(FRAMES));
    let check = stats.stages.iter().find(|s| s.0 == "check").expect("the lane's latency");
    assert_eq!(check.1.count(), FRAMES);
    // and the published result is what the standard graph publishes; the failing sink is that sink's
    // failure, not an unpublished frame
    assert_eq!(stats.frames_published, FRAMES);
    assert!(stats.frames_failed.is_empty(), "{:?}", stats.frames_failed);
    assert_eq!(stats.sink_failures.get("failing"), Some(&FRAMES), "{:?}", stats.sink_failures);
    assert_eq!(stats.output_digest, plain.output_digest);
    assert_eq!(stats.points_total, plain.points_total);
}

/// A stage that does nothing, under any name.
struct Named(&'static str);

impl Stage for Named {
    fn name(&self) -> &'static str {
        self.0
    }
    fn process(&mut self, _: &mut Work) -> abvs_runtime_core::error::Result<()> {
        Ok(())
    }
}

fn build(description: &'static str, stages: Vec<Box<dyn Stage>>) -> String {
    let source = ReplaySource::open(Session::open(&fixture()).unwrap()).unwrap();
    match Graph::from_description(source, cfg().out, description, stages, Vec::new()) {
        Ok(g) => format!("ok: {:?}", g.stage_names()),
        Err(e) => e.to_string(),
    }
}

#[test]
fn descriptions_must_place_exactly_the_stages_given() {
    let ok = build("a = x, y; output = z", vec![Box::new(Named("z")), Box::new(Named("x")), Box::new(Named("y"))]);
    assert_eq!(ok, r#"ok: ["source", "a", "output"]"#);
    let e = build("a = x, w; output = z", vec![Box::new(Named("x")), Box::new(Named("z"))]);
    assert!(e.contains("no stage `w`"), "{e}");
    let e = build("a = x; output = z", vec![Box::new(Named("x")), Box::new(Named("z")), Box::new(Named("y"))]);
    assert!(e.contains("stage `y` is given but not placed"), "{e}");
    let e = build("a = x; a = z", vec![Box::new(Named("x")), Box::new(Named("z"))]);
    assert!(e.contains("lane name `a` used twice"), "{e}");
    let e = build("a x", vec![]);
    assert!(e.contains("has no `=`"), "{e}");
    // depth is filled on the output lane only (its buffer is lent there)
    let depth = || -> Box<dyn Stage> { Box::new(DepthStage::new(DepthConfig::default())) };
    let e = build("a = depth; output = z", vec![depth(), Box::new(Named("z"))]);
    assert!(e.contains("stage `depth` writes depth and must be on the output lane, not `a`"), "{e}");
    assert!(build("a = x; output = depth", vec![depth(), Box::new(Named("x"))]).starts_with("ok"));
}

/// Works until the calling thread has used `ms` of CPU time (not wall time).
fn burn(ms: i64) {
    let t = abvs_runtime_core::cpu::thread_cpu_ns();
    let mut x = 0u64;
    while abvs_runtime_core::cpu::thread_cpu_ns() - t < ms * 1_000_000 {
        x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
    }
}

/// A stage that works 3 ms of CPU per frame on its lane's thread, and whose named helper thread works 40 ms
/// once, on the first frame, and lives until the stage is dropped.
struct Burner {
    helper: Option<std::sync::mpsc::Sender<()>>,
}

impl Stage for Burner {
    fn name(&self) -> &'static str {
        "burner"
    }
    fn start(&mut self, _: &mut StageContext) -> abvs_runtime_core::error::Result<()> {
        let (tx, rx) = std::sync::mpsc::channel::<()>();
        std::thread::Builder::new()
            .name("burner-helper".into())
            .spawn(move || {
                if rx.recv().is_ok() {
                    burn(40);
                }
                // until the stage is dropped (the sender with it)
                while rx.recv().is_ok() {}
            })
            .unwrap();
        self.helper = Some(tx);
        Ok(())
    }
    fn process(&mut self, _: &mut Work) -> abvs_runtime_core::error::Result<()> {
        burn(3);
        if let Some(tx) = &self.helper {
            let _ = tx.send(());
        }
        Ok(())
    }
}

#[test]
fn cpu_time_is_counted_per_lane_and_per_named_thread() {
    let mut g = standard();
    let at = g.lanes.len() - 1;
    g.lanes.insert(at, Lane { name: "burn", stages: vec![Box::new(Burner { helper: None })] });
    let stats = runner::run(g, &cfg().run_config()).unwrap();
    let cpu = stats.cpu.as_ref().expect("a finished run reports its CPU");
    let lane = |n: &str| cpu.lanes.iter().find(|l| l.0 == n).map(|l| l.1).unwrap_or_else(|| panic!("lane {n}"));
    let names: Vec<&str> = cpu.lanes.iter().map(|l| l.0).collect();
    assert_eq!(names, ["source", "rectify", "disparity", "burn", "output"]);
    // the burning lane: its 3 ms per frame, and not much more (it only burns)
    let burned = lane("burn");
    assert!((3_000_000 * FRAMES as i64..6_000_000 * FRAMES as i64).contains(&burned), "{burned} ns");
    // the helper: its 40 ms, by its name, among the other threads; nothing is counted twice
    let helper = cpu.others.get("burner-helper").copied().unwrap_or(0);
    assert!((40_000_000..80_000_000).contains(&helper), "{:?}", cpu.others);
    let lanes: i64 = cpu.lanes.iter().map(|l| l.1).sum();
    let others: i64 = cpu.others.values().sum();
    assert!(cpu.process_ns >= lanes + helper, "{} < {lanes} + {helper}", cpu.process_ns);
    assert!(others <= cpu.process_ns - lanes + 5_000_000, "others {others} beyond the rest");
    // per frame in the JSON and in the table
    let elapsed = stats.extra["elapsed_s"].as_f64().unwrap();
    let j = stats.json(elapsed);
    let per = j["cpu"]["lanes_ms_per_frame"]["burn"].as_f64().unwrap();
    assert!((3.0..6.0).contains(&per), "{per}");
    assert_eq!(j["cpu"]["frames"], serde_json::json!(FRAMES));
    let table = stats.table(elapsed);
    assert!(
        table.contains("CPU per frame: ") && table.contains("burn ") && table.contains("burner-helper "),
        "{table}"
    );
}

/// A stage that takes `ms` of wall time per frame (sleeping: the test does not depend on the machine's
/// speed) and, if `sheds`, lets a frame pass when its lane is behind ([`Stage::shed`]).
struct Slow {
    ms: u64,
    sheds: bool,
    done: Arc<Mutex<(u64, u64)>>,
}

impl Stage for Slow {
    fn name(&self) -> &'static str {
        "slow"
    }
    fn process(&mut self, _: &mut Work) -> abvs_runtime_core::error::Result<()> {
        std::thread::sleep(std::time::Duration::from_millis(self.ms));
        self.done.lock().unwrap().0 += 1;
        Ok(())
    }
    fn shed(&mut self, _: &mut Work) -> bool {
        self.done.lock().unwrap().1 += self.sheds as u64;
        self.sheds
    }
}

/// The frames that reach the output lane, by seq.
struct Last(Arc<Mutex<Vec<u64>>>);

impl Stage for Last {
    fn name(&self) -> &'static str {
        "last"
    }
    fn process(&mut self, w: &mut Work) -> abvs_runtime_core::error::Result<()> {
        self.0.lock().unwrap().push(w.seq);
        Ok(())
    }
}

/// A paced replay (25 fps, frames dropped under overload) through a lane that needs 55 ms a frame: without
/// shedding the lane's queue drops whole frames; a stage that sheds lets the frames it cannot do pass
/// without its work, and every frame reaches the output, in order. A lossless run never sheds.
#[test]
fn a_lane_behind_sheds_its_extra_instead_of_dropping_frames() {
    const N: u64 = 40;
    let run = |sheds: bool, lossless: bool| {
        let done = Arc::new(Mutex::new((0, 0)));
        let seen = Arc::new(Mutex::new(Vec::new()));
        let slow: Box<dyn Stage> = Box::new(Slow { ms: 55, sheds, done: done.clone() });
        let last: Box<dyn Stage> = Box::new(Last(seen.clone()));
        let source = ReplaySource::open(Session::open(&fixture()).unwrap()).unwrap();
        let g = Graph::from_description(source, cfg().out, "extra = slow; output = last", vec![slow, last], vec![])
            .unwrap();
        let c = PipelineConfig { lossless, paced: !lossless, frames: Some(N), ..Default::default() };
        let stats = runner::run(g, &c.run_config()).unwrap();
        let (done, seen) = (*done.lock().unwrap(), seen.lock().unwrap().clone());
        (stats.frames_dropped, done, seen)
    };
    let (dropped, (processed, shed), seen) = run(true, false);
    assert_eq!(dropped, 0, "processed {processed}, shed {shed}");
    assert_eq!(processed + shed, N);
    assert!(shed >= 5 && processed >= 10, "processed {processed}, shed {shed}");
    assert_eq!(seen, (0..N).collect::<Vec<_>>(), "every frame published, in order");
    // the same lane without shedding loses whole frames
    let (dropped, (processed, _), seen) = run(false, false);
    assert!(dropped >= 5, "dropped {dropped}, processed {processed}");
    assert_eq!(seen.len() as u64 + dropped, N);
    // lossless: every frame gets the work
    let (dropped, (processed, shed), _) = run(true, true);
    assert_eq!((dropped, processed, shed), (0, N, 0));
}
