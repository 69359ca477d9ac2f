//! Frames are matched by identity, never by position: a session with one frame file missing replays with
//! that frame counted in frames_failed (with its reason) and every other frame scored against its own
//! ground truth, exactly as in the intact session.
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::{Arc, Mutex};

use abvs_camera::StereoCalibration;
use abvs_disparity::factory as disparity;
use abvs_runtime::pipeline::{run_replay, PipelineConfig};
use abvs_runtime::sources::replay::ReplaySource;
use abvs_runtime::tasks::kinematics::{EyeFk, StereoKinematics};
use abvs_runtime_core::messages::Published;
use abvs_runtime_core::session::Session;
use abvs_runtime_core::sink::Sink;
use abvs_runtime_core::stats::{DepthError, RunStats};
use abvs_sim::truth::TruthSink;

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/session")
}

/// The truth sink, with the depth error of each frame recorded by session seq.
struct PerFrame {
    truth: TruthSink,
    last: DepthError,
    frames: Arc<Mutex<Vec<(u64, DepthError)>>>,
}

impl Sink for PerFrame {
    fn name(&self) -> &'static str {
        "per-frame truth"
    }
    fn consume(&mut self, out: &Published) -> abvs_runtime_core::error::Result<()> {
        self.truth.consume(out)?;
        let (now, last) = (self.truth.error(), self.last);
        self.frames.lock().unwrap().push((
            out.session_seq,
            DepthError {
                abs_rel_sum: now.abs_rel_sum - last.abs_rel_sum,
                sq_sum: now.sq_sum - last.sq_sum,
                points: now.points - last.points,
                pixels: now.pixels - last.pixels,
            },
        ));
        self.last = now;
        Ok(())
    }
    fn finish(&mut self, stats: &mut RunStats) {
        self.truth.finish(stats);
    }
}

/// Replays a session once (lossless, SGBM) and returns its stats and each published frame's depth error.
fn replay(dir: &Path, frames: Option<u64>) -> (RunStats, Vec<(u64, DepthError)>) {
    let session = Session::open(dir).unwrap();
    let stereo = StereoCalibration::read_yaml(session.path(&session.meta.stereo)).unwrap();
    let kin = StereoKinematics::new(
        EyeFk::load(&session.path(&session.meta.fk[0])).unwrap(),
        EyeFk::load(&session.path(&session.meta.fk[1])).unwrap(),
        stereo.rotation,
        stereo.translation_mm / 1000.0,
    );
    let cfg = PipelineConfig { lossless: true, paced: false, frames, ..Default::default() };
    let eng = disparity::engine("sgbm", None, (cfg.out.width, cfg.out.height), 48.0, 2).unwrap();
    let per_frame = Arc::new(Mutex::new(Vec::new()));
    let sink = PerFrame {
        truth: TruthSink::for_session(&session, 8).unwrap().expect("synthetic session"),
        last: DepthError::default(),
        frames: per_frame.clone(),
    };
    let source = ReplaySource::open(session).unwrap();
    let stats = run_replay(source, kin, (stereo.left, stereo.right), eng, vec![Box::new(sink)], cfg).unwrap();
    let v = per_frame.lock().unwrap().clone();
    (stats, v)
}

fn fixture_copy() -> tempfile::TempDir {
    let d = tempfile::tempdir().unwrap();
    assert!(Command::new("cp").arg("-r").arg(fixture()).arg(d.path().join("s")).status().unwrap().success());
    d
}

#[test]
fn a_missing_frame_is_counted_and_shifts_nothing() {
    let (intact, intact_frames) = replay(&fixture(), None);
    assert_eq!(intact.frames_published, 50);
    assert_eq!(intact_frames.iter().map(|(s, _)| *s).collect::<Vec<_>>(), (0..50).collect::<Vec<u64>>());

    let d = fixture_copy();
    let s = d.path().join("s");
    std::fs::remove_file(s.join("frames/left_000020.png")).unwrap();
    let (gap, gap_frames) = replay(&s, None);
    let j = gap.json(1.0);
    eprintln!("with frame 20 missing: {}", serde_json::to_string(&j).unwrap());
    assert_eq!(j["frames_failed"], serde_json::json!({ "frame file missing": 1 }), "{j}");
    assert_eq!((gap.frames_in, gap.frames_published, gap.frames_dropped), (50, 49, 0));
    assert_eq!(j["bad_frame_files"], 1);
    assert_eq!(j["truth_frames_unscored"], 0);

    // every other frame: its own seq, the same depth error as in the intact session
    let seqs: Vec<u64> = gap_frames.iter().map(|(s, _)| *s).collect();
    assert_eq!(seqs, (0..50).filter(|&s| s != 20).collect::<Vec<u64>>());
    let mut worst = 0f64;
    for (seq, e) in &gap_frames {
        let (_, i) = intact_frames.iter().find(|(s, _)| s == seq).unwrap();
        assert_eq!((e.points, e.pixels), (i.points, i.pixels), "frame {seq}: points scored");
        let (a, b) = (e.abs_rel_sum / e.points.max(1) as f64, i.abs_rel_sum / i.points.max(1) as f64);
        worst = worst.max((a - b).abs());
        // Not bit-exact: a replay maps the session's times onto CLOCK_MONOTONIC when it starts, so the link
        // angles of any two runs (gap or not) differ in their last bits, and now and then a point's float
        // rounding flips (seen: frame 8, 2e-8 relative, in about one run of three). A frame scored against
        // another frame's truth differs by percent.
        assert!((a - b).abs() <= 1e-6 * b.max(1e-3), "frame {seq}: abs_rel {a} with the gap, {b} intact");
        assert!((e.sq_sum - i.sq_sum).abs() <= 1e-6 * i.sq_sum.max(1e-9), "frame {seq}: rmse differs");
    }
    eprintln!("largest per-frame abs_rel difference: {worst:e}");
    // and so the session's error is the intact one without frame 20
    let e = gap.depth_error.unwrap();
    let (_, f20) = intact_frames[20];
    let whole = intact.depth_error.unwrap();
    assert_eq!(e.points, whole.points - f20.points);
    let expect = (whole.abs_rel_sum - f20.abs_rel_sum) / (whole.points - f20.points) as f64;
    assert!((e.abs_rel_sum / e.points as f64 - expect).abs() < 1e-8 * expect, "{e:?} vs {expect}");
}

#[test]
fn a_bad_frame_is_counted_again_on_every_loop_and_seq_keeps_its_meaning() {
    let d = fixture_copy();
    let s = d.path().join("s");
    // the first frame unreadable (a PNG signature, then garbage), the last of the wrong size
    std::fs::write(s.join("frames/right_000000.png"), b"\x89PNG\r\n\x1a\nnot a png").unwrap();
    image::GrayImage::new(8, 8).save(s.join("frames/left_000049.png")).unwrap();
    let (stats, frames) = replay(&s, Some(120));
    let j = stats.json(1.0);
    // 120 rows reached: rows 0 and 49 of the first two loops and row 0 of the third fail
    assert_eq!(
        j["frames_failed"],
        serde_json::json!({ "frame file unreadable": 3, "frame file of the wrong size": 2 }),
        "{j}"
    );
    assert_eq!((stats.frames_in, stats.frames_published), (120, 115), "{j}");
    // looped frames are scored against the truth of their session seq
    assert!(frames.iter().all(|(seq, _)| *seq != 0 && *seq != 49));
    assert_eq!(frames.len(), 115);
    assert_eq!(j["truth_frames_unscored"], 0);
    let abs_rel = j["depth_error"]["abs_rel"].as_f64().unwrap();
    assert!(abs_rel < 0.05, "looped replay scored against the right truth: abs_rel {abs_rel}");
}
