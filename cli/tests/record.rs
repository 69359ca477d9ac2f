//! Recording from live sources, end to end: a simulated drive board (a separate `abvs sim board
//! --session` process) streams the fixture's encoders, preceded by each eye's start-up roll,
//! through a real pseudo-terminal; two stand-in cameras deliver the fixture's frames in real time
//! through the capture threads and the pairer; the recorder homes both eyes, writes a session, and
//! `abvs run` replays that session. The recording must reproduce the fixture: the same pixels,
//! the same frame times, the same homed counts, encoder times within the clock mapping's error.
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use abvs_runtime::record::{record, RecordConfig};
use abvs_runtime::session::{EncoderRecord, Session};
use abvs_runtime::sinks::session_writer::{CalibFiles, SessionWriter};
use abvs_runtime::sinks::stats::monotonic_ns;
use abvs_runtime::sources::encoder_link::SessionBoard;
use abvs_runtime::sources::encoder_stream::EncoderStream;
use abvs_runtime::sources::pairing::PairerConfig;
use abvs_runtime::sources::v4l_capture::{CaptureError, FrameSource, StereoCapture};
use abvs_runtime::sources::Frame;

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/session")
}

/// A camera delivering recorded frames when CLOCK_MONOTONIC reaches their end of exposure, stamped
/// with their recorded start of exposure + `shift`.
struct ReplayCamera {
    frames: Vec<(i64, i64, Vec<u8>)>,
    width: u32,
    height: u32,
    shift: i64,
    next: usize,
}

impl FrameSource for ReplayCamera {
    fn next_frame(&mut self, mut gray: Vec<u8>) -> Result<Frame, CaptureError> {
        let Some((t, exposure, pixels)) = self.frames.get(self.next) else {
            std::thread::sleep(Duration::from_millis(20));
            return Err(CaptureError::Timeout { path: "replay".into() });
        };
        let t_start = t + self.shift;
        let wait = t_start + exposure - monotonic_ns();
        if wait > 0 {
            std::thread::sleep(Duration::from_nanos(wait as u64));
        }
        gray.clear();
        gray.extend_from_slice(pixels);
        self.next += 1;
        Ok(Frame {
            seq: self.next as u64,
            t_start_ns: t_start,
            exposure_ns: *exposure,
            width: self.width,
            height: self.height,
            gray,
        })
    }

    fn frame_len(&self) -> usize {
        (self.width * self.height) as usize
    }
}

fn gray(p: &Path) -> Vec<u8> {
    image::open(p).unwrap_or_else(|e| panic!("{}: {e}", p.display())).to_luma8().into_raw()
}

/// For each recorded row (in order), the fixture row of the same eye nearest in time after the
/// shift; returns the time errors (ns) after checking the counts are the fixture's.
fn match_encoders(recorded: &[EncoderRecord], fixture: &[EncoderRecord], shift: i64) -> Vec<i64> {
    let mut errors = vec![];
    for eye in 0..2u8 {
        let fx: Vec<&EncoderRecord> = fixture.iter().filter(|r| r.eye == eye).collect();
        let mut j = 0;
        // Rows before the session's first sample are the end of the homing roll and the rest after it.
        let from = fx[0].t_ns + shift - 500_000;
        for r in recorded.iter().filter(|r| r.eye == eye && r.t_ns >= from) {
            while j + 1 < fx.len() && (fx[j + 1].t_ns + shift - r.t_ns).abs() <= (fx[j].t_ns + shift - r.t_ns).abs() {
                j += 1;
            }
            let f = fx[j];
            assert_eq!(
                (r.count1, r.count2, r.count3),
                (f.count1, f.count2, f.count3),
                "eye {eye} at {} ns: recorded counts differ from the fixture's nearest sample",
                r.t_ns
            );
            errors.push(r.t_ns - (f.t_ns + shift));
        }
    }
    errors
}

#[test]
fn records_the_fixture_from_a_board_process_and_stand_in_cameras() {
    let fx = Session::open(&fixture()).unwrap();
    let (w, h) = (fx.meta.width, fx.meta.height);
    let mut cams: [Vec<(i64, i64, Vec<u8>)>; 2] = [vec![], vec![]];
    for f in &fx.frames {
        cams[0].push((f.t_start_ns, f.exposure_ns, gray(&fx.path(&f.left))));
        cams[1].push((f.t_start_ns, f.exposure_ns, gray(&fx.path(&f.right))));
    }
    let early = 5;
    for cam in cams.iter_mut() {
        // Frames while the links are still rolling (before homing can be decided): counted, not recorded.
        let (t0, e, px) = cam[0].clone();
        let before: Vec<_> =
            (0..early).map(|i| (t0 - 1_200_000_000 - (early - i) * 40_000_000, e, px.clone())).collect();
        cam.splice(0..0, before);
    }

    let t_first_enc = fx.encoders.iter().map(|r| r.t_ns).min().unwrap();
    let start_ns = monotonic_ns() + 1_500_000_000;
    let shift = start_ns - t_first_enc;
    let (master, slave) = serialport::TTYPort::pair().expect("pseudo-terminal pair");
    let name = serialport::SerialPort::name(&slave).expect("pty name");
    let mut board = Command::new(env!("CARGO_BIN_EXE_abvs"))
        .args(["sim", "board", "--port", &name, "--session"])
        .arg(fixture())
        .args(["--start-ns", &start_ns.to_string(), "--seed", "7", "--corrupt-every", "997"])
        .spawn()
        .unwrap();
    let mut master = master;
    serialport::SerialPort::set_timeout(&mut master, Duration::from_millis(100)).unwrap();
    let encoders = EncoderStream::spawn(master, name.clone(), 16_384);

    let [l, r] = cams;
    let cam = |frames| ReplayCamera { frames, width: w, height: h, shift, next: 0 };
    let mut capture = StereoCapture::from_sources(cam(l), cam(r), PairerConfig::default());
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("recorded");
    let writer =
        SessionWriter::create(&out, &CalibFiles::from_dir(&fixture().join("calib")), 25.0, "test".into()).unwrap();
    let cfg = RecordConfig {
        frames: Some(fx.frames.len() as u64),
        homing_timeout: Duration::from_secs(20),
        ..Default::default()
    };
    let stop = AtomicBool::new(false);
    let (session, stats) = record(&mut capture, encoders, writer, &cfg, &stop, &mut |_| {});
    assert!(board.wait().unwrap().success());
    drop(slave);
    let rec = session.unwrap_or_else(|e| panic!("{e}\n{stats:#?}"));
    eprintln!("{stats:#?}");

    // Every pair is accounted for; the early ones were refused for want of homing.
    assert_eq!(stats.pairs_before_homing, early as u64, "{stats:#?}");
    assert_eq!(stats.pairs_written, fx.frames.len() as u64, "{stats:#?}");
    assert_eq!(stats.pairs_dropped_writer + stats.write_errors, 0);
    assert_eq!(stats.pairs_in, stats.pairs_written + stats.pairs_before_homing);
    // Homing found the board's raw-count origins exactly.
    let origin = SessionBoard::from_seed(7).origin;
    assert_eq!(stats.encoders.home_counts, [Some(origin[0]), Some(origin[1])]);
    // The link faults were seen and counted.
    assert!(stats.encoders.link.crc_errors > 0 && stats.encoders.link.lost_frames > 0, "{:?}", stats.encoders.link);

    // Frames: same pixels, same times (shifted).
    assert_eq!(rec.frames.len(), fx.frames.len());
    for (a, b) in rec.frames.iter().zip(&fx.frames) {
        assert_eq!(a.t_start_ns, b.t_start_ns + shift);
        assert_eq!(a.exposure_ns, b.exposure_ns);
        assert!(gray(&rec.path(&a.left)) == gray(&fx.path(&b.left)), "{}", a.left);
        assert!(gray(&rec.path(&a.right)) == gray(&fx.path(&b.right)), "{}", a.right);
    }
    // Encoders: the fixture's homed counts, less the corrupted frames, at the mapped times.
    let lost = stats.encoders.link.lost_frames as usize;
    assert!(rec.encoders.len() + lost >= fx.encoders.len(), "{} recorded, {lost} lost", rec.encoders.len());
    let mut dt: Vec<i64> = match_encoders(&rec.encoders, &fx.encoders, shift);
    dt.sort_by_key(|x| x.abs());
    let p50 = dt[dt.len() / 2].abs() as f64 * 1e-6;
    let max = dt.last().unwrap().abs() as f64 * 1e-6;
    eprintln!("encoder time error: p50 {p50:.3} ms, max {max:.3} ms over {} samples", dt.len());
    assert!(p50 < 0.5 && max < 3.0, "p50 {p50:.3} ms, max {max:.3} ms");

    // The recording replays through the whole pipeline.
    let json = tmp.path().join("run.json");
    let o = Command::new(env!("CARGO_BIN_EXE_abvs"))
        .args(["run", "--engine", "sgbm", "--no-publish", "--lossless", "--quiet", "--session"])
        .arg(&out)
        .arg("--stats-json")
        .arg(&json)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["frames_published"], serde_json::json!(fx.frames.len()), "{v}");
}

#[test]
fn record_refuses_missing_devices_and_bad_targets_clearly() {
    let tmp = tempfile::tempdir().unwrap();
    let calib = fixture().join("calib");
    let run = |args: &[&str]| {
        let o = Command::new(env!("CARGO_BIN_EXE_abvs")).arg("record").args(args).output().unwrap();
        assert!(!o.status.success());
        String::from_utf8_lossy(&o.stderr).to_string()
    };
    let out = tmp.path().join("s");
    let out_s = out.to_str().unwrap();
    let calib_s = calib.to_str().unwrap();
    // No encoder port.
    let e = run(&["--calib", calib_s, "--out", out_s, "--encoders", "/dev/nonexistent-tty"]);
    assert!(e.contains("/dev/nonexistent-tty"), "{e}");
    // A port, but no camera (no V4L2 on this machine).
    let (_master, slave) = serialport::TTYPort::pair().unwrap();
    let name = serialport::SerialPort::name(&slave).unwrap();
    let e = run(&["--calib", calib_s, "--out", out_s, "--encoders", &name, "--left", "/dev/video-abvs-missing"]);
    assert!(e.contains("/dev/video-abvs-missing") && e.contains("no such video device"), "{e}");
    assert!(!out.exists(), "a failed start must not leave a session directory behind");
    // A calibration directory without the files.
    let e = run(&["--calib", tmp.path().to_str().unwrap(), "--out", out_s]);
    assert!(e.contains("stereo.yaml"), "{e}");
    // An existing, non-empty session directory.
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("keep"), "x").unwrap();
    let e = run(&["--calib", calib_s, "--out", out_s]);
    assert!(e.contains("not empty"), "{e}");
}
