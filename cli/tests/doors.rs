//! Knocks on every door: for every subcommand and every numeric flag of clap's command tree
//! (`abvs cli-tree`, so a new flag is covered without editing this test), the values 0, -1, NaN,
//! inf, 1e30 and a huge size, and negative ones after a space (`--flag -1`, as users type them).
//! The rule: no panic, abort or signal, no check taking more than a few seconds, and a refusal
//! naming the flag (never clap's "unexpected argument '-1'"). Values may be accepted (`--seed 0`): the cases
//! stop after every check that precedes work (clap's value parsers, grid sizes, output paths),
//! as `abvs --validate-only` does, so an accepted value costs nothing. They run in one process
//! (`abvs validate-lines`, a panic caught per case; an abort ends the process and fails the test);
//! a few run as their own processes to show the same answers there.
use serde_json::Value;
use std::collections::BTreeSet;
use std::io::{BufRead, BufReader, Write};
use std::path::Path;
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use std::time::Instant;

const ABVS: &str = env!("CARGO_BIN_EXE_abvs");
/// The longest a check may take before its refusal (ms).
const SLOW_MS: f64 = 3000.0;

struct Outcome {
    code: Option<i32>,
    stderr: String,
    ms: f64,
}

/// One `abvs validate-lines` process answering a line per case.
struct Batch {
    child: Child,
    stdin: ChildStdin,
    stdout: BufReader<ChildStdout>,
}

impl Batch {
    fn start() -> Batch {
        let mut child = Command::new(ABVS)
            .arg("validate-lines")
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("start abvs validate-lines");
        let stdin = child.stdin.take().unwrap();
        let stdout = BufReader::new(child.stdout.take().unwrap());
        Batch { child, stdin, stdout }
    }

    fn run(&mut self, args: &[String]) -> Outcome {
        writeln!(self.stdin, "{}", serde_json::to_string(args).unwrap()).expect("write a case");
        self.stdin.flush().unwrap();
        let mut line = String::new();
        let n = self.stdout.read_line(&mut line).expect("read an answer");
        if n == 0 {
            let status = self.child.wait().unwrap();
            panic!("abvs validate-lines died ({status}: an abort?) on: abvs {}", args.join(" "));
        }
        let v: Value = serde_json::from_str(&line).expect("a JSON answer");
        Outcome {
            code: v["code"].as_i64().map(|c| c as i32),
            stderr: v["error"].as_str().unwrap_or_default().to_string(),
            ms: v["ms"].as_f64().unwrap_or(f64::INFINITY),
        }
    }
}

/// A case as its own process, as a user runs it (with --validate-only).
fn process(args: &[String]) -> Outcome {
    let t0 = Instant::now();
    let o = Command::new(ABVS).arg("--validate-only").args(args).output().expect("run abvs");
    Outcome {
        code: o.status.code(),
        stderr: String::from_utf8_lossy(&o.stderr).into_owned(),
        ms: t0.elapsed().as_secs_f64() * 1e3,
    }
}

fn tree() -> Vec<Value> {
    let o = Command::new(ABVS).arg("cli-tree").output().expect("abvs cli-tree");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice::<Value>(&o.stdout).expect("JSON").as_array().expect("a list").clone()
}

fn str_of(v: &Value, k: &str) -> String {
    v[k].as_str().unwrap_or_default().to_string()
}

fn list(v: &Value, k: &str) -> Vec<String> {
    v[k].as_array().map(|a| a.iter().filter_map(|x| x.as_str().map(String::from)).collect()).unwrap_or_default()
}

/// A value the argument takes: its first choice, its default, or a plain one of its kind (a file
/// that does not exist, in a directory that does).
fn filler(a: &Value, tmp: &Path) -> String {
    if let Some(c) = list(a, "choices").into_iter().next() {
        return c;
    }
    if let Some(d) = list(a, "defaults").into_iter().next() {
        return d;
    }
    match a["kind"].as_str() {
        Some("float") | Some("int") => "1".into(),
        Some("vec3") => "0,1,0".into(),
        Some("vec2") => "1,1".into(),
        _ => tmp.join(format!("missing-{}", str_of(a, "id"))).to_string_lossy().into_owned(),
    }
}

/// An argument as command-line words.
fn words(a: &Value, value: &str) -> Vec<String> {
    if a["positional"].as_bool() == Some(true) {
        vec![value.to_string()]
    } else if a["kind"] == "flag" {
        vec![str_of(a, "name")]
    } else {
        vec![format!("{}={value}", str_of(a, "name"))]
    }
}

/// The arguments clap says are missing ("the following required arguments were not provided").
fn missing<'a>(stderr: &str, args: &'a [Value]) -> Vec<&'a Value> {
    let Some(i) = stderr.find("required arguments were not provided") else { return vec![] };
    stderr[i..]
        .lines()
        .skip(1)
        .take_while(|l| l.starts_with("  "))
        .filter_map(|l| {
            let w = l.split_whitespace().next().unwrap_or_default();
            args.iter().find(|a| str_of(a, "name") == w || format!("<{}>", str_of(a, "id").to_uppercase()) == w)
        })
        .collect()
}

struct Leaf {
    path: Vec<String>,
    args: Vec<Value>,
    groups: Vec<Value>,
    /// ids of the arguments a plain invocation needs, with their values
    base: Vec<(String, String)>,
}

impl Leaf {
    fn arg(&self, id: &str) -> &Value {
        self.args.iter().find(|a| a["id"] == id).expect("known id")
    }

    fn command(&self, base: &[(String, String)], extra: &[String]) -> Vec<String> {
        let mut v = self.path.clone();
        for (id, val) in base {
            v.extend(words(self.arg(id), val));
        }
        v.extend_from_slice(extra);
        v
    }

    /// Runs with `extra`, adding what clap says is missing (required-unless, requires) as plain values.
    fn run(&self, b: &mut Batch, base: &mut Vec<(String, String)>, extra: &[String], tmp: &Path) -> Outcome {
        for _ in 0..4 {
            let o = b.run(&self.command(base, extra));
            let add = missing(&o.stderr, &self.args);
            if add.is_empty() || o.code == Some(0) {
                return o;
            }
            for a in add {
                base.push((str_of(a, "id"), filler(a, tmp)));
            }
        }
        b.run(&self.command(base, extra))
    }

    /// Whether `a` and `b` cannot be given together (clap's conflicts, a one-of group).
    fn exclusive(&self, a: &str, b: &str) -> bool {
        let conflicts = |x: &str, y: &str| list(self.arg(x), "conflicts").iter().any(|c| c == y);
        conflicts(a, b)
            || conflicts(b, a)
            || self.groups.iter().any(|g| {
                let m = list(g, "args");
                g["multiple"] != true && m.iter().any(|x| x == a) && m.iter().any(|x| x == b)
            })
    }
}

/// What is wrong with an answer, if anything.
fn judge(o: &Outcome, name: &str) -> Option<String> {
    if o.code.is_none() {
        Some("killed by a signal (an abort?)".into())
    } else if o.code == Some(101) || o.stderr.contains("panicked") {
        Some("panicked".into())
    } else if o.ms > SLOW_MS {
        Some(format!("took {:.0} ms to answer", o.ms))
    } else if o.code != Some(0) && !o.stderr.contains(name) {
        Some(format!("refused without naming {name}"))
    } else {
        None
    }
}

#[test]
fn every_numeric_flag_refuses_bad_values_by_name_without_panic_or_hang() {
    let tmp = tempfile::tempdir().unwrap();
    let t0 = Instant::now();
    let mut leaves: Vec<Leaf> = tree()
        .into_iter()
        .map(|l| {
            let args: Vec<Value> = l["args"].as_array().unwrap().clone();
            let mut base: Vec<(String, String)> = args
                .iter()
                .filter(|a| a["required"] == true)
                .map(|a| (str_of(a, "id"), filler(a, tmp.path())))
                .collect();
            for g in l["groups"].as_array().unwrap() {
                let m = list(g, "args");
                if g["required"] == true && !base.iter().any(|(id, _)| m.contains(id)) {
                    let a = args.iter().find(|a| a["id"] == m[0].as_str()).unwrap();
                    base.push((m[0].clone(), filler(a, tmp.path())));
                }
            }
            Leaf { path: list(&l, "path"), args, groups: l["groups"].as_array().unwrap().clone(), base }
        })
        .collect();
    assert!(leaves.len() > 30, "{} subcommands", leaves.len());

    // Each subcommand's plain invocation passes the checks: what a refusal below names is the knocked flag.
    let mut b = Batch::start();
    let mut failures = Vec::new();
    for l in &mut leaves {
        let mut base = l.base.clone();
        let o = l.run(&mut b, &mut base, &[], tmp.path());
        if o.code != Some(0) {
            failures.push(format!(
                "abvs {}: the plain invocation is refused:\n{}",
                l.command(&base, &[]).join(" "),
                o.stderr
            ));
        }
        l.base = base;
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));

    let scalars = ["0", "-1", "NaN", "inf", "1e30", "100000000000000"];
    let mut cases: Vec<(usize, String, String)> = Vec::new();
    for (i, l) in leaves.iter().enumerate() {
        for a in &l.args {
            let vals: Vec<String> = match a["kind"].as_str() {
                Some("float") | Some("int") => scalars.iter().map(|s| s.to_string()).collect(),
                Some("vec3") => scalars.iter().map(|s| format!("{s},{s},{s}")).collect(),
                Some("vec2") => scalars.iter().map(|s| format!("{s},{s}")).collect(),
                _ => continue,
            };
            for v in vals {
                cases.push((i, str_of(a, "id"), v));
            }
        }
    }
    let flags: BTreeSet<String> = cases
        .iter()
        .map(|(i, id, _)| format!("{} {}", leaves[*i].path.join(" "), str_of(leaves[*i].arg(id), "name")))
        .collect();
    for must in ["kin psc --step-deg", "sim dataset --grid-n", "calib fit --hidden", "echo --timeout-s", "run --frames"]
    {
        assert!(flags.contains(must), "{must} not knocked on: {flags:?}");
    }

    let mut found = Vec::new();
    let mut accepted = 0;
    for (i, id, v) in &cases {
        let l = &leaves[*i];
        let a = l.arg(id);
        let name = str_of(a, "name");
        let mut base: Vec<(String, String)> =
            l.base.iter().filter(|(b, _)| b != id && !l.exclusive(id, b)).cloned().collect();
        let o = l.run(&mut b, &mut base, &words(a, v), tmp.path());
        let what = format!("abvs {}", l.command(&base, &words(a, v)).join(" "));
        if let Some(bad) = judge(&o, &name) {
            found.push(format!("{what}: {bad}:\n{}", o.stderr));
        }
        accepted += usize::from(o.code == Some(0));
        if o.code == Some(0) && std::env::var_os("DOORS_VERBOSE").is_some() {
            eprintln!("accepted: {what}");
        }
    }
    // a negative number after a space is the flag's value, refused (or taken) by the flag's own check: never
    // clap's "unexpected argument '-1'", which names no flag
    let mut spaced = 0;
    for (i, id, v) in cases.iter().filter(|(_, _, v)| v == "-1") {
        let l = &leaves[*i];
        let a = l.arg(id);
        if a["positional"].as_bool() == Some(true) || !matches!(a["kind"].as_str(), Some("float") | Some("int")) {
            continue;
        }
        let name = str_of(a, "name");
        let mut base: Vec<(String, String)> =
            l.base.iter().filter(|(b, _)| b != id && !l.exclusive(id, b)).cloned().collect();
        for v in [v.as_str(), "-0.5", "-1e30"] {
            let extra = vec![name.clone(), v.to_string()];
            let o = l.run(&mut b, &mut base, &extra, tmp.path());
            let what = format!("abvs {}", l.command(&base, &extra).join(" "));
            if let Some(bad) = judge(&o, &name) {
                found.push(format!("{what}: {bad}:\n{}", o.stderr));
            } else if o.stderr.contains("unexpected argument") {
                found.push(format!("{what}: the value after the space read as a flag:\n{}", o.stderr));
            }
            spaced += 1;
        }
    }
    assert!(spaced > 100, "{spaced} negative values after a space");
    // the same answers as processes of their own: a refusal, a size refused by a check, an accepted value
    for (args, flag) in [
        (vec!["kin", "psc", "--step-deg=NaN", "--out", "x.csv"], "--step-deg"),
        (vec!["kin", "psc", "--step-deg=1e-9", "--out", "x.csv"], "--step-deg"),
        (vec!["sim", "unit", "--seed=0", "--out", "x.toml"], "--seed"),
        (vec!["run", "--readout-ms", "-5"], "--readout-ms"),
        (vec!["run", "--motion-gate-px", "-1"], "--motion-gate-px"),
        (vec!["sim", "session", "--out", "new-session", "--time-offset-ms", "-5"], "--time-offset-ms"),
    ] {
        let args: Vec<String> = args.into_iter().map(String::from).collect();
        let (o, p) = (b.run(&args), process(&args));
        assert_eq!(o.code, p.code, "abvs {args:?}: {} vs {}", o.stderr, p.stderr);
        if let Some(bad) = judge(&p, flag) {
            found.push(format!("abvs {args:?} (process): {bad}:\n{}", p.stderr));
        }
    }
    eprintln!(
        "{} cases on {} flags of {} subcommands, {} accepted, in {:.1} s",
        cases.len(),
        flags.len(),
        leaves.len(),
        accepted,
        t0.elapsed().as_secs_f64()
    );
    assert!(found.is_empty(), "{} doors failed:\n{}", found.len(), found.join("\n"));
}

/// A readout longer than a frame period is refused wherever it enters, by name, before any work (issue 37:
/// `run --readout-ms 1000` and `[motion] readout_ms = 1000` were accepted; session.toml refused it).
#[test]
fn a_readout_longer_than_a_frame_is_refused_by_name() {
    let tmp = tempfile::tempdir().unwrap();
    let fixture = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/session");
    let log = tmp.path().join("check.csv");
    let run = |args: &[&std::ffi::OsStr]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_abvs")).arg("run").args(args).output().unwrap()
    };
    let o = run(&[
        "--session".as_ref(),
        fixture.as_os_str(),
        "--no-publish".as_ref(),
        "--readout-ms".as_ref(),
        "1000".as_ref(),
        "--self-check-log".as_ref(),
        log.as_os_str(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("--readout-ms") && err.contains("one frame period"), "{err}");
    assert!(err.contains("25 fps") && !log.exists(), "{err}");
    // the same value in a configuration's [motion]
    let o = run(&[
        "--session".as_ref(),
        fixture.as_os_str(),
        "--readout-ms".as_ref(),
        "1000".as_ref(),
        "--print-config".as_ref(),
    ]);
    let cfg = tmp.path().join("c.toml");
    std::fs::write(&cfg, &o.stdout).unwrap();
    assert!(String::from_utf8_lossy(&o.stdout).contains("readout_ms = 1000"), "{o:?}");
    let o = run(&["--config".as_ref(), cfg.as_os_str(), "--no-publish".as_ref()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("[motion] readout_ms") && err.contains("one frame period"), "{err}");
}

/// A flag's paragraph of `abvs <cmd> --help`: from its line to the next flag's.
fn help_of(cmd: &[&str], flag: &str) -> String {
    let o = Command::new(ABVS).args(cmd).arg("--help").output().unwrap();
    let help = String::from_utf8_lossy(&o.stdout).into_owned();
    let start = help
        .lines()
        .position(|l| l.trim_start().starts_with(&format!("{flag} ")))
        .unwrap_or_else(|| panic!("abvs {} --help has no {flag}:\n{help}", cmd.join(" ")));
    let lines: Vec<&str> = help.lines().skip(start).collect();
    let end = lines.iter().skip(1).position(|l| l.trim_start().starts_with('-')).map_or(lines.len(), |e| e + 1);
    lines[..end].join(" ")
}

/// Help gives each timing flag's unit, range and true default (issue 37: the ranges of `--readout-ms`,
/// `--exposure-ms`, `--pursuit-deg-s`, `--time-offset-ms`, `--motion-gate-px`, `--seconds`, `--stats-window`
/// and `--rounds` were left out; `run --readout-ms` showed "[default: 30]" though a replay uses the session's;
/// `sim session --fps` said "up to 1000" and refused 1000).
#[test]
fn help_states_each_timing_flags_unit_range_and_true_default() {
    for (cmd, flag, must) in [
        (&["run"][..], "--readout-ms", &["(ms, 0 up to one frame period", "a replay: the session's"][..]),
        (&["run"], "--exposure-ms", &["(ms, above 0 up to one frame period"]),
        (&["run"], "--time-offset-ms", &["(ms, -1000 to 1000", "the session's"]),
        (&["run"], "--motion-gate-px", &["(rectified px, above 0 up to 1e9)", "[default: 3"]),
        (&["run"], "--seconds", &["(s, above 0 up to 1e9"]),
        (&["run"], "--stats-window", &["(s, above 0 up to 1e9)", "[default: 60]"]),
        (&["record"], "--readout-ms", &["(ms, 0 up to one frame period", "30 live and for `record`"]),
        (&["sim", "session"], "--fps", &["(Hz, above 0 up to 200)"]),
        (&["sim", "session"], "--readout-ms", &["(ms, 0 up to one frame period - 4 ms"]),
        (&["sim", "session"], "--exposure-ms", &["(ms, 0 up to one frame period"]),
        (&["sim", "session"], "--pursuit-deg-s", &["(deg/s, 0 to 500)"]),
        (&["sim", "session"], "--time-offset-ms", &["(ms, 0 to 10)"]),
        (&["calib", "self-check"], "--rounds", &["(0 to 10)"]),
    ] {
        let h = help_of(cmd, flag);
        for m in must {
            assert!(h.contains(m), "abvs {} {flag}: no `{m}` in: {h}", cmd.join(" "));
        }
    }
    let h = help_of(&["run"], "--readout-ms");
    assert!(!h.contains("[default: 30]"), "a replay's readout is the session's: {h}");
    // what help says is what the flag takes
    let o = process(&["sim", "session", "--out", "new-session", "--fps", "200"].map(String::from));
    assert_eq!(o.code, Some(1), "200 Hz passes the flag (refused with the default readout): {}", o.stderr);
    assert!(o.stderr.contains("--readout-ms") && o.stderr.contains("--fps 200"), "{}", o.stderr);
    let o = process(&["sim", "session", "--out", "new-session", "--fps", "1000"].map(String::from));
    assert!(o.code == Some(2) && o.stderr.contains("--fps") && o.stderr.contains("200"), "{}", o.stderr);
}

/// Every timing value is checked against the frame period where it enters, the refusal naming the flag or the
/// file's field, before any work (issue 37): sim session's readout and exposure, record's, a live run's
/// exposure, and session.toml's exposure_ms.
#[test]
fn timing_values_are_checked_against_the_frame_period_by_name() {
    let refused = |args: &[&str], names: &[&str]| {
        let args: Vec<String> = args.iter().map(|s| s.to_string()).collect();
        let o = process(&args);
        assert_eq!(o.code, Some(1), "abvs {args:?}: {}", o.stderr);
        for n in names {
            assert!(o.stderr.contains(n), "abvs {args:?}: no `{n}` in {}", o.stderr);
        }
    };
    refused(&["sim", "session", "--out", "s", "--fps", "100"], &["--readout-ms 30", "--fps 100", "6.000"]);
    refused(&["sim", "session", "--out", "s", "--fps", "50", "--exposure-ms", "30"], &["--exposure-ms 30", "20.000"]);
    refused(&["record", "--calib", "c", "--out", "o", "--fps", "50"], &["--readout-ms 30", "--fps 50"]);
    refused(&["record", "--calib", "c", "--out", "o", "--exposure-ms", "50"], &["--exposure-ms 50", "40.000"]);
    // the simulated head's timing (`[source.sim]`): refused by field and flag
    for (flag, v, field) in [
        ("--fps", "300", "source.sim.fps (--fps)"),
        ("--readout-ms", "39", "source.sim.readout_ms (--readout-ms)"),
        ("--exposure-ms", "45", "source.sim.exposure_ms (--exposure-ms)"),
    ] {
        let o = Command::new(ABVS).args(["run", "--source", "sim", "--no-publish", "--frames", "1", flag, v]).output();
        let err = String::from_utf8_lossy(&o.as_ref().unwrap().stderr).into_owned();
        assert!(!o.unwrap().status.success() && err.contains(field), "{flag} {v}: {err}");
    }
    // a live run's exposure: refused before the cameras are opened
    let tmp = tempfile::tempdir().unwrap();
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/session");
    let o = Command::new(ABVS)
        .args(["run", "--live", "--no-publish", "--exposure-ms", "50", "--left", "/nonexistent/video"])
        .arg("--calib")
        .arg(fixture.join("calib"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("exposure_ms (--exposure-ms)") && err.contains("one frame period"),
        "{err}"
    );
    // session.toml: an exposure longer than its frame period, named by file, line and field
    let s = tmp.path().join("session");
    std::fs::create_dir(&s).unwrap();
    for e in std::fs::read_dir(&fixture).unwrap() {
        let e = e.unwrap();
        if e.file_name() != "session.toml" {
            std::os::unix::fs::symlink(e.path(), s.join(e.file_name())).unwrap();
        }
    }
    let toml = std::fs::read_to_string(fixture.join("session.toml")).unwrap();
    assert!(toml.contains("exposure_ms = 4.0"), "{toml}");
    std::fs::write(s.join("session.toml"), toml.replace("exposure_ms = 4.0", "exposure_ms = 50.0")).unwrap();
    let o = Command::new(ABVS).args(["run", "--no-publish", "--frames", "1", "--session"]).arg(&s).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("session.toml:") && err.contains("exposure_ms"), "{err}");
    assert!(err.contains("one frame period"), "{err}");
}
