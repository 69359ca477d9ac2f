//! `abvs run --self-check`: the flags reach the runtime (stats JSON `self_check`, the CSV log, the
//! printed line), the configuration carries them, and the run's depth is unchanged by the check.
use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

fn abvs() -> Command {
    Command::new(env!("CARGO_BIN_EXE_abvs"))
}

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/session")
}

/// `abvs run` (SGBM, lossless, no publishing) with `extra`; the stats JSON and stdout.
fn run(dir: &Path, extra: &[&str]) -> (Value, String) {
    let stats = dir.join(format!("stats-{}.json", extra.len()));
    let out = abvs()
        .args([
            "run",
            "--resolution",
            "320x240",
            "--no-publish",
            "--engine",
            "sgbm",
            "--lossless",
            "--truth-stride",
            "0",
            "--session",
        ])
        .arg(fixture())
        .arg("--stats-json")
        .arg(&stats)
        .args(extra)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v = serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
    (v, String::from_utf8_lossy(&out.stdout).into_owned())
}

#[test]
fn self_check_flags_log_and_stats() {
    let tmp = tempfile::tempdir().unwrap();
    let log = tmp.path().join("check.csv");
    let (plain, _) = run(tmp.path(), &["--no-self-check"]);
    assert!(plain.get("self_check").is_none(), "turned off");
    let (default, stdout) = run(tmp.path(), &[]);
    assert_eq!(
        default["self_check"]["frames"], 10,
        "on by default, every 5th of 50 frames: {:#}",
        default["self_check"]
    );
    assert!(stdout.contains("self-check: 10 frames"), "{stdout}");
    let (v, stdout) = run(tmp.path(), &["--self-check-log", log.to_str().unwrap(), "--self-check-every", "2"]);
    let sc = &v["self_check"];
    assert_eq!(sc["frames"], 25, "every 2nd of 50 frames: {sc:#}");
    assert_eq!(sc["frames_skipped"], 0, "lossless waits for the worker: {sc:#}");
    let r: Vec<f64> = sc["rotation_error_deg"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
    assert!(r.iter().map(|x| x * x).sum::<f64>().sqrt() < 0.05, "{sc:#}");
    assert!(sc["vertical_px"]["p50"].as_f64().unwrap() < 0.1 && sc["matches_p50"].as_u64().unwrap() > 100, "{sc:#}");
    assert!(stdout.contains("self-check: 25 frames"), "{stdout}");
    // the check reads the pipeline's output and changes none of it
    assert_eq!(v["output_digest"], plain["output_digest"]);
    let text = std::fs::read_to_string(&log).unwrap();
    let rows: Vec<&str> = text.lines().collect();
    assert_eq!(rows.len(), 26, "{text}");
    assert!(rows[0].starts_with("seq,t_ns,l1_deg,l2_deg,l3_deg,r1_deg,r2_deg,r3_deg,matches,vertical_p50_px"));
    assert!(rows[1].starts_with("0,") && rows[2].starts_with("2,"), "{text}");

    // the configuration carries it (and refuses nonsense)
    let out = abvs().args(["run", "--self-check", "--print-config"]).output().unwrap();
    let cfg = String::from_utf8_lossy(&out.stdout);
    assert!(cfg.contains("[sinks.self_check]") && cfg.contains("enabled = true"), "{cfg}");
    let bad = tmp.path().join("bad.toml");
    std::fs::write(&bad, cfg.replace("every = 5", "every = 0")).unwrap();
    let out = abvs().args(["run", "--config"]).arg(&bad).output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("sinks.self_check"), "{out:?}");
}

/// A fixture copy whose eye `eye` (0 left, 1 right) runs on its true unit model with +1 % encoder scale on
/// every link: an FK error zero at home and growing away from it.
fn wrong_eye_copy(tmp: &Path, eye: usize) -> PathBuf {
    let copy = tmp.join(format!("wrong{eye}"));
    assert!(Command::new("cp").arg("-r").arg(fixture()).arg(&copy).status().unwrap().success());
    let mut unit = abvs_eye::UnitModel::load(&copy.join(format!("truth/unit{eye}.toml"))).unwrap();
    unit.effects.encoder_scale.enabled = true;
    unit.effects.encoder_scale.relative_error.iter_mut().for_each(|e| *e += 0.01);
    unit.save(&copy.join(format!("calib/eye{eye}.toml"))).unwrap();
    let toml = std::fs::read_to_string(copy.join("session.toml")).unwrap();
    let (from, to) = (format!("\"calib/eye{eye}\""), format!("\"calib/eye{eye}.toml\""));
    assert!(toml.contains(&from));
    std::fs::write(copy.join("session.toml"), toml.replace(&from, &to)).unwrap();
    copy
}

/// A copy of session `src` whose eyes run on their true unit models, `wrong` (0 left, 1 right) with +1 %
/// encoder scale on every link.
fn truth_copy(src: &Path, dst: &Path, wrong: Option<usize>) {
    assert!(Command::new("cp").arg("-r").arg(src).arg(dst).status().unwrap().success());
    let mut toml = std::fs::read_to_string(dst.join("session.toml")).unwrap();
    for eye in 0..2 {
        let mut unit = abvs_eye::UnitModel::load(&dst.join(format!("truth/unit{eye}.toml"))).unwrap();
        if wrong == Some(eye) {
            unit.effects.encoder_scale.enabled = true;
            unit.effects.encoder_scale.relative_error.iter_mut().for_each(|e| *e += 0.01);
        }
        unit.save(&dst.join(format!("calib/eye{eye}.toml"))).unwrap();
        toml = toml.replace(&format!("\"calib/eye{eye}\""), &format!("\"calib/eye{eye}.toml\""));
    }
    std::fs::write(dst.join("session.toml"), toml).unwrap();
}

/// Issue 37's held-out check as a test, on a session nothing was chosen on (seed 73): fixations near and far
/// (0.3-2 m, so that the eyes verge by different amounts), 40 frames at 10 fps (over 15 fixations), 320x240.
/// With both eyes' true units it reads no significant error; with the right eye's +1 % encoder scale it names
/// the right eye (the left's would fit the fixations far worse). ~60 s debug: one render, two replays.
#[test]
fn a_rendered_session_with_fixations_near_and_far_names_the_wrong_eye() {
    let tmp = tempfile::tempdir().unwrap();
    let s = tmp.path().join("s");
    let o = abvs()
        .args(["sim", "session", "--out"])
        .arg(&s)
        .args(["--seed", "73", "--frames", "40", "--fps", "10", "--width", "320", "--height", "240"])
        .args(["--fk-method", "mh", "--pursuit-deg-s", "30", "--fixation-m", "0.3..2"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for (name, wrong) in [("none", None), ("right", Some(1))] {
        let copy = tmp.path().join(name);
        truth_copy(&s, &copy, wrong);
        let log = tmp.path().join(format!("{name}.csv"));
        let o = abvs()
            .args(["run", "--resolution", "320x240", "--no-publish", "--engine", "sgbm", "--lossless", "--quiet"])
            .args(["--truth-stride", "0", "--self-check-every", "1", "--session"])
            .arg(&copy)
            .arg("--self-check-log")
            .arg(&log)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let a = abvs_selfcheck::attribution::attribute(&log).unwrap();
        assert!(a.fixations >= abvs_selfcheck::attribution::MIN_FIXATIONS_TO_NAME, "{} fixations", a.fixations);
        match wrong {
            None => assert_eq!(a.verdict, abvs_selfcheck::attribution::Verdict::NoError, "{:?}", a.eye_test),
            Some(_) => assert_eq!(
                a.verdict.eye(),
                Some(abvs_selfcheck::attribution::Eye::Right),
                "{}: {:?}",
                a.verdict,
                a.eye_test
            ),
        }
    }
}

/// `abvs calib self-check` on logs of the fixture: as calibrated nothing to report; with one eye's model
/// wrong away from home it names that eye and puts the largest error far from home.
#[test]
fn the_offline_report_names_the_wrong_eye_and_where() {
    let tmp = tempfile::tempdir().unwrap();
    let report = |log: &Path, name: &str| -> Value {
        let out = tmp.path().join(name);
        let o = abvs().args(["calib", "self-check", "--log"]).arg(log).arg("--out").arg(&out).output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        for f in ["report.md", "error_by_frame.png", "error_over_gaze.png"] {
            assert!(out.join(f).metadata().unwrap().len() > 100, "{f}");
        }
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap()
    };
    let log = tmp.path().join("ok.csv");
    let out = abvs()
        .args([
            "run",
            "--resolution",
            "320x240",
            "--no-publish",
            "--engine",
            "sgbm",
            "--lossless",
            "--quiet",
            "--truth-stride",
            "0",
        ])
        .args(["--self-check-every", "1", "--self-check-log"])
        .arg(&log)
        .output()
        .unwrap();
    assert!(out.status.success());
    let ok = report(&log, "ok");
    assert!(ok["verdict"].as_str().unwrap().starts_with("no significant error"), "{ok:#}");
    // the library returns the same verdict, typed: a caller needs no report to parse
    let typed = abvs_selfcheck::attribution::attribute(&log).unwrap();
    assert_eq!(typed.verdict, abvs_selfcheck::attribution::Verdict::NoError);
    assert_eq!(ok["verdict"], typed.verdict.to_string());
    for (eye, name) in [(1, "right"), (0, "left")] {
        let copy = wrong_eye_copy(tmp.path(), eye);
        let log = tmp.path().join(format!("wrong{eye}.csv"));
        let out = abvs()
            .args([
                "run",
                "--resolution",
                "320x240",
                "--no-publish",
                "--engine",
                "sgbm",
                "--lossless",
                "--quiet",
                "--truth-stride",
                "0",
            ])
            .arg("--session")
            .arg(&copy)
            .args(["--self-check-every", "1", "--self-check-log"])
            .arg(&log)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        // the runtime warned while it ran
        assert!(String::from_utf8_lossy(&out.stderr).contains("warning: self-check"), "{out:?}");
        let v = report(&log, &format!("wrong{eye}"));
        let verdict = v["verdict"].as_str().unwrap();
        let typed = abvs_selfcheck::attribution::attribute(&log).unwrap().verdict;
        assert_eq!(verdict, typed.to_string());
        let named = typed.eye().map(|e| e.name());
        assert!(
            named == Some(name) || matches!(typed, abvs_selfcheck::attribution::Verdict::EitherEye { .. }),
            "{typed:?}"
        );
        // The fixture's eyes now pursue targets together (their gazes correlate at 1.00 in yaw and pitch over
        // its fixations): the report must then say it cannot tell the eyes apart rather than guess, and
        // still find the pose-dependent error; with eyes that verge independently it names the eye.
        let together = verdict.contains("the poses do not tell the eyes apart")
            && verdict.contains("either eye's model")
            && verdict.contains("record fixations near and far");
        assert!(verdict.starts_with(&format!("the {name} eye's model")) || together, "{v:#}");
        // the error is largest far from home: that fixation's gaze is more than 10 deg off in yaw or pitch
        let g = &v["worst_fixation"][format!("{name}_gaze_deg")];
        let off = g[0].as_f64().unwrap().abs().max(g[1].as_f64().unwrap().abs());
        assert!(off > 10.0 && v["worst_fixation"]["mean_error_norm_deg"].as_f64().unwrap() > 0.1, "{v:#}");
    }
}

/// At the runtime's default 640x480 the calibrated fixture reads "no significant error" too (issue 37: the
/// matcher's pixel-sized windows read its poses up to 0.12 deg off about y there, a false alarm "varies with
/// the pose ... left 77 %, right 74 %"; the true error is under 0.01 deg). ~20 s: one 640x480 SGBM replay.
#[test]
fn the_calibrated_fixture_reads_no_error_at_640x480() {
    let tmp = tempfile::tempdir().unwrap();
    let log = tmp.path().join("ok.csv");
    let out = abvs()
        .args(["run", "--resolution", "640x480", "--no-publish", "--engine", "sgbm", "--lossless", "--quiet"])
        .args(["--truth-stride", "0", "--self-check-every", "1", "--self-check-log"])
        .arg(&log)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let dir = tmp.path().join("report");
    let o = abvs()
        .args(["calib", "self-check", "--rounds", "0", "--log"])
        .arg(&log)
        .arg("--out")
        .arg(&dir)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: Value = serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap();
    assert!(v["verdict"].as_str().unwrap().starts_with("no significant error"), "{v:#}");
    // every frame within 0.04 deg (the truth: under 0.01; it read 0.116 before)
    assert!(v["error_norm_deg"]["max"].as_f64().unwrap() < 0.04, "{v:#}");
}

/// `calib self-check` checks every file it will write or edit before any work (the replay rounds take
/// minutes), and an edit that fails at the end takes neither report.md nor summary.json with it.
#[test]
fn self_check_outputs_are_checked_first_and_a_failed_write_keeps_the_report() {
    let tmp = tempfile::tempdir().unwrap();
    let log = tmp.path().join("check.csv");
    run(tmp.path(), &["--self-check-log", log.to_str().unwrap(), "--self-check-every", "1"]);
    let out = tmp.path().join("report");
    let cfg = tmp.path().join("robot.toml");
    let self_check = |extra: &[&std::ffi::OsStr]| {
        abvs().args(["calib", "self-check", "--log"]).arg(&log).arg("--out").arg(&out).args(extra).output().unwrap()
    };
    // an absent configuration: refused at once, by name, before the rounds and before --out is made
    let t0 = std::time::Instant::now();
    let o = self_check(&["--write-config".as_ref(), cfg.as_os_str()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("--write-config") && err.contains("no such file"), "{err}");
    assert!(!out.exists(), "refused before any work");
    assert!(t0.elapsed().as_secs_f64() < 10.0, "refused after {:?}", t0.elapsed());
    // a session without session.toml: the same
    let o = self_check(&["--write-session".as_ref(), tmp.path().as_os_str()]);
    assert!(String::from_utf8_lossy(&o.stderr).contains("--write-session"), "{o:?}");
    // a TOML file that passes the check but cannot take the estimate (`motion` is not a table): the edit fails
    // at the end; the report and the summary are written, and the failure is named
    std::fs::write(&cfg, "motion = 5\n").unwrap();
    let o = self_check(&["--rounds".as_ref(), "0".as_ref(), "--write-config".as_ref(), cfg.as_os_str()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("--write-config") && err.contains("not a table"), "{err}");
    assert!(out.join("report.md").is_file() && out.join("summary.json").is_file(), "{err}");
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("Not written into the configuration"), "{md}");
    assert_eq!(std::fs::read_to_string(&cfg).unwrap(), "motion = 5\n");
}

/// A log is fitted and replayed only with its own run (issue 37): a match log of another run is refused by
/// name, another run's `.run.toml` is not replayed (said why), nor its own edited after the run or naming a
/// session other than the one the run read (both by SHA-256), a missing one is reported, and a run whose
/// rolling-shutter correction was off is not fitted as if it had been on.
#[test]
fn logs_are_tied_to_their_run() {
    let tmp = tempfile::tempdir().unwrap();
    let p = |n: &str| tmp.path().join(n);
    // a and b replay with no timing applied, so that their fits ask for rounds (the fixture's true timing,
    // applied, leaves nothing to refine and no round to refuse)
    let zero = ["--time-offset-ms", "0", "--readout-ms", "0"];
    for (name, extra) in [("a", &zero[..]), ("b", &zero[..]), ("off", &["--rolling-shutter", "off"][..])] {
        let log = p(&format!("{name}.csv"));
        let mut args = vec!["--self-check-every", "1", "--self-check-log", log.to_str().unwrap()];
        args.extend_from_slice(extra);
        run(tmp.path(), &args);
    }
    let check = |log: &str, out: &str| {
        let o = abvs().args(["calib", "self-check", "--log"]).arg(p(log)).arg("--out").arg(p(out)).output().unwrap();
        (
            o.status.success(),
            String::from_utf8_lossy(&o.stdout).into_owned(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        )
    };
    // another run's match log beside the frame log: refused, both named
    std::fs::copy(p("a.matches.csv"), p("a.keep")).unwrap();
    std::fs::copy(p("b.matches.csv"), p("a.matches.csv")).unwrap();
    let (ok, _, err) = check("a.csv", "r1");
    assert!(!ok && err.contains("logs of different runs") && err.contains("a.matches.csv"), "{err}");
    std::fs::rename(p("a.keep"), p("a.matches.csv")).unwrap();
    // its own configuration, edited after the run (pointed at another session): not replayed, said why
    let own = std::fs::read_to_string(p("a.run.toml")).unwrap();
    assert!(own.contains("# self-check config_sha256 = ") && own.contains("# self-check session_sha256 = "), "{own}");
    let line = own.lines().find(|l| l.starts_with("session = ")).expect("the run.toml names its session");
    let edited = own.replace(line, &format!("session = {:?}", tmp.path().join("other-session")));
    std::fs::write(p("a.run.toml"), &edited).unwrap();
    let (ok, out, err) = check("a.csv", "r5");
    assert!(ok && out.contains("no rounds") && out.contains("was edited after its run"), "{out}\n{err}");
    assert!(!err.contains("round 1"), "{err}");
    // the session is not the one the run read (its session.toml changed since, or another one there)
    let header = own.lines().find(|l| l.starts_with("# self-check session_sha256 = ")).unwrap();
    std::fs::write(p("a.run.toml"), own.replace(header, &format!("# self-check session_sha256 = {}", "0".repeat(64))))
        .unwrap();
    let (ok, out, err) = check("a.csv", "r6");
    assert!(ok && out.contains("no rounds") && out.contains("is not the session the run replayed"), "{out}\n{err}");
    assert!(!err.contains("round 1"), "{err}");
    // another run's configuration: not replayed, and said so
    std::fs::copy(p("b.run.toml"), p("a.run.toml")).unwrap();
    let (ok, out, err) = check("a.csv", "r2");
    assert!(ok, "{err}");
    assert!(out.contains("no rounds") && out.contains("another run's configuration"), "{out}");
    assert!(!p("r2/round-1.csv").exists() && !err.contains("round 1"), "{err}");
    // none: said so
    std::fs::remove_file(p("a.run.toml")).unwrap();
    let (ok, out, _) = check("a.csv", "r3");
    assert!(ok && out.contains("no rounds: no") && out.contains("a.run.toml"), "{out}");
    // the correction off: no timing fitted as if it had been on
    let (ok, out, _) = check("off.csv", "r4");
    assert!(ok && out.contains("timing: no estimate") && out.contains("rolling-shutter correction was off"), "{out}");
    let v: Value = serde_json::from_str(&std::fs::read_to_string(p("r4/summary.json")).unwrap()).unwrap();
    assert!(v["timing"]["reason"].as_str().unwrap().contains("rolling-shutter"), "{v:#}");
}
