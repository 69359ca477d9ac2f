//! The examples (`runtime/examples/`) run as a user runs them, on the fixture at 320x240, and what they print
//! is checked: `embed` processes every frame and its handle counted them, `custom_sink`'s sink received every
//! frame's depth in order (its own hash of the depth equals the runtime's output digest, and `embed`'s), and
//! `subscribe`'s child process published depth, confidence and clouds that the parent received, every seq on
//! every topic. `cargo test` builds the examples beside the tests (target/<profile>/examples/) but does not run
//! them: this does, and fails when one was not built.
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::Command;

/// An example's binary, built by `cargo test` next to this test's directory.
fn example(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("the test's path");
    // target/<profile>/deps/examples-<hash> -> target/<profile>/examples/<name>
    let p = exe.parent().and_then(|d| d.parent()).expect("target/<profile>").join("examples").join(name);
    assert!(p.is_file(), "{} not built: `cargo test --workspace` builds the examples", p.display());
    p
}

/// Runs an example; its stdout, or a failure with both streams.
fn run(name: &str, args: &[&str]) -> String {
    let o = Command::new(example(name)).args(args).output().expect("run the example");
    let (out, err) = (String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "example {name} {args:?} failed ({}):\n{out}\n{err}", o.status);
    out.into_owned()
}

/// The words after `key` on the line that starts with `line`, as `word -> next word` pairs.
fn fields(out: &str, line: &str) -> BTreeMap<String, String> {
    let l = out.lines().find(|l| l.starts_with(line)).unwrap_or_else(|| panic!("no line `{line}` in:\n{out}"));
    let w: Vec<&str> = l[line.len()..].split_whitespace().collect();
    w.windows(2).map(|p| (p[0].to_string(), p[1].to_string())).collect()
}

fn num(f: &BTreeMap<String, String>, k: &str) -> u64 {
    f.get(k).and_then(|v| v.parse().ok()).unwrap_or_else(|| panic!("no number `{k}` in {f:?}"))
}

#[test]
fn embed_and_custom_sink_see_every_frame_and_agree_on_the_depth() {
    let embed = run("embed", &["8"]);
    let e = fields(&embed, "frames_in");
    assert!(embed.lines().any(|l| l.starts_with("frames_in 8 ")), "{embed}");
    assert_eq!((num(&e, "frames_published"), num(&e, "frames_dropped")), (8, 0), "{embed}");
    // the handle's live counts reached the same numbers
    assert!(embed.contains("(handle: 8 / 8 / 0)"), "{embed}");
    let digest = embed.lines().find_map(|l| l.strip_prefix("output_digest ")).expect("a digest").to_string();
    assert_eq!(digest.len(), 16, "{embed}");

    let sink = run("custom_sink", &["8"]);
    let s = fields(&sink, "sink");
    assert_eq!((num(&s, "frames"), num(&s, "out_of_order")), (8, 0), "{sink}");
    assert!(num(&s, "valid_pixels") > 8 * 320 * 240 / 4, "the fixture has depth on most pixels:\n{sink}");
    let r = fields(&sink, "runtime");
    assert_eq!(num(&r, "frames_published"), 8, "{sink}");
    assert_eq!(s["digest"], r["output_digest"], "the sink saw other depth than the runtime published:\n{sink}");
    assert_eq!(r["output_digest"], digest, "two lossless runs of one configuration differ:\n{embed}\n{sink}");
}

#[test]
fn a_bad_argument_is_refused_by_name() {
    let o = Command::new(example("embed")).arg("ten").output().expect("run the example");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("FRAMES `ten`"), "{err}");
}

#[test]
fn subscribe_receives_every_published_frame_on_every_topic_from_another_process() {
    let out = run("subscribe", &["12"]);
    let published = num(&fields(&out, "publisher"), "frames_published");
    assert!((1..=12).contains(&published), "{out}");
    let seqs = |topic: &str| {
        let f = fields(&out, &format!("subscriber {topic}"));
        let n: u64 = out
            .lines()
            .find_map(|l| l.strip_prefix(&format!("subscriber {topic} ")))
            .and_then(|l| l.split_whitespace().next())
            .and_then(|n| n.parse().ok())
            .unwrap_or_else(|| panic!("no count for {topic}:\n{out}"));
        (n, f.get("seqs").cloned().unwrap_or_default())
    };
    let (depth, confidence, cloud) = (seqs("depth"), seqs("confidence"), seqs("cloud"));
    assert_eq!(depth.0, published, "every published depth map arrives:\n{out}");
    assert_eq!(confidence, depth, "{out}");
    assert_eq!(cloud, depth, "{out}");
    assert_eq!(num(&fields(&out, "subscriber seq_gaps"), "malformed"), 0, "{out}");
}

/// `gaze` points the eyes through the running runtime's handle: on the fixture (a replay, no drive board) its
/// goal is answered by a frame's state, refused by name, and the run goes on.
#[test]
fn gaze_goals_are_answered_and_a_replay_refuses_them_by_name() {
    let out = run("gaze", &[]);
    assert!(out.lines().any(|l| l.starts_with("goal 1: phase refused reason no_board")), "{out}");
    let published: u64 = out
        .lines()
        .find_map(|l| l.strip_prefix("frames_published "))
        .and_then(|n| n.trim().parse().ok())
        .unwrap_or_else(|| panic!("no frames_published line in:\n{out}"));
    assert!((1..=12).contains(&published), "{out}");
}

/// Every Rust block of the README and the guides under docs/ is lines of one of the runtime's examples (which
/// the tests above build and run), so no page can show code that no longer builds. The runtime guide's "Use it
/// from your own process" shows `custom_sink`.
#[test]
fn the_guides_show_code_of_the_examples() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let examples: Vec<(String, Vec<String>)> = std::fs::read_dir(root.join("runtime/examples"))
        .expect("runtime/examples")
        .map(|e| e.expect("an entry").path())
        .filter(|p| p.extension().is_some_and(|x| x == "rs"))
        .map(|p| {
            let text = std::fs::read_to_string(&p).expect("an example");
            (p.display().to_string(), text.lines().map(|l| l.trim().to_string()).collect())
        })
        .collect();
    let mut pages = vec![root.join("README.md")];
    for e in std::fs::read_dir(root.join("docs")).expect("docs/") {
        let p = e.expect("an entry").path();
        if p.extension().is_some_and(|x| x == "md") {
            pages.push(p);
        }
    }
    let mut blocks = 0;
    for page in &pages {
        let text = std::fs::read_to_string(page).expect("a page");
        for block in text.split("```rust\n").skip(1) {
            let block = block.split("```").next().expect("its end");
            let shown: Vec<&str> = block.lines().map(str::trim).filter(|l| !l.is_empty()).collect();
            let ok = examples.iter().any(|(_, lines)| shown.iter().all(|l| lines.iter().any(|x| x == l)));
            assert!(ok, "{}: a Rust block is not lines of one example of runtime/examples/:\n{block}", page.display());
            blocks += 1;
        }
    }
    let runtime = std::fs::read_to_string(root.join("docs/runtime.md")).expect("docs/runtime.md");
    let section = runtime.split("## Use it from your own process").nth(1).expect("the runtime guide's section");
    let block = section.split("```rust\n").nth(1).and_then(|b| b.split("```").next()).expect("its code block");
    let custom = &examples.iter().find(|(p, _)| p.ends_with("custom_sink.rs")).expect("custom_sink.rs").1;
    let shown: Vec<&str> = block.lines().map(str::trim).filter(|l| !l.is_empty()).collect();
    assert!(shown.len() > 10, "{block}");
    assert!(shown.iter().all(|l| custom.iter().any(|x| x == l)), "{block}");
    assert!(blocks >= 1);
}
