//! Every documented refusal of a session's index files and of a model manifest: the error names the file,
//! the line and the field (session.toml), or the file and line (frames.csv), and paths that leave their
//! directory are refused.
use std::path::{Path, PathBuf};

use abvs_runtime_core::session::Session;

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../fixtures/session")
}

/// A session directory with the fixture's index files (no frames: `Session::open` reads only the index).
struct Index {
    dir: tempfile::TempDir,
    toml: String,
    frames: String,
}

impl Index {
    fn new() -> Index {
        let dir = tempfile::tempdir().unwrap();
        let r = |f: &str| std::fs::read_to_string(fixture().join(f)).unwrap();
        std::fs::write(dir.path().join("encoders.csv"), r("encoders.csv")).unwrap();
        Index { dir, toml: r("session.toml"), frames: r("frames.csv") }
    }

    /// Opens the session with session.toml's `line` (1-based) replaced by `with`.
    fn open_toml_line(&self, key: &str, with: &str) -> Result<Session, String> {
        let mut found = false;
        let text: Vec<String> = self
            .toml
            .lines()
            .map(|l| {
                if !found && l.starts_with(&format!("{key} =")) {
                    found = true;
                    with.to_string()
                } else {
                    l.to_string()
                }
            })
            .collect();
        assert!(found, "no `{key} =` line in the fixture's session.toml");
        self.open(&(text.join("\n") + "\n"), &self.frames)
    }

    fn open(&self, toml: &str, frames: &str) -> Result<Session, String> {
        std::fs::write(self.dir.path().join("session.toml"), toml).unwrap();
        std::fs::write(self.dir.path().join("frames.csv"), frames).unwrap();
        Session::open(self.dir.path()).map_err(|e| e.to_string())
    }

    /// The 1-based line of `key =` in the fixture's session.toml.
    fn line_of(&self, key: &str) -> usize {
        self.toml.lines().position(|l| l.starts_with(&format!("{key} ="))).unwrap() + 1
    }
}

fn assert_names(e: &str, file_line: &str, field: &str, what: &str) {
    assert!(
        e.contains(file_line) && e.contains(&format!("`{field}`")) && e.contains(what),
        "error `{e}` should name {file_line}, `{field}` and say `{what}`"
    );
}

#[test]
fn the_fixture_index_opens() {
    let ix = Index::new();
    let s = ix.open(&ix.toml, &ix.frames).unwrap();
    assert_eq!(s.frames.len(), 50);
}

#[test]
fn out_of_range_numbers_in_session_toml_name_file_line_and_field() {
    let ix = Index::new();
    let at = |k: &str| format!("session.toml:{}", ix.line_of(k));
    for (key, line, what) in [
        // (loop_period_ns 0 used to hang `abvs run`: the encoder replay never advanced)
        ("loop_period_ns", "loop_period_ns = 0", "0 is out of range"),
        ("loop_period_ns", "loop_period_ns = -2000000000", "out of range"),
        // a period shorter than the recording: looped timestamps would go back
        ("loop_period_ns", "loop_period_ns = 1000000000", "not longer than"),
        ("width", "width = 0", "0 is out of range"),
        ("height", "height = 1000000", "1000000 is out of range"),
        ("fps", "fps = 0.0", "out of range"),
        ("fps", "fps = -25.0", "out of range"),
        ("fps", "fps = nan", "out of range"),
        ("fps", "fps = inf", "out of range"),
        ("format", "format = \"abvs-session/9\"", "expected `abvs-session/1`"),
    ] {
        let e = ix.open_toml_line(key, line).map(|_| ()).unwrap_err();
        assert_names(&e, &at(key), key, what);
    }
    // gravity spans several lines: its first line is named
    let toml = ix.toml.replace("gravity = [\n    0.0,\n    1.0,", "gravity = [\n    0.0,\n    2.0,");
    assert_ne!(toml, ix.toml);
    let e = ix.open(&toml, &ix.frames).map(|_| ()).unwrap_err();
    assert_names(&e, &at("gravity"), "gravity", "not a unit vector");
}

#[test]
fn a_bad_toml_type_names_file_line_and_field() {
    let ix = Index::new();
    let e = ix.open_toml_line("width", "width = \"800\"").map(|_| ()).unwrap_err();
    assert_names(&e, &format!("session.toml:{}", ix.line_of("width")), "width", "invalid type");
    let e = ix.open_toml_line("loop_period_ns", "loop_period_ns = 2.5").map(|_| ()).unwrap_err();
    assert_names(&e, &format!("session.toml:{}", ix.line_of("loop_period_ns")), "loop_period_ns", "invalid type");
    // not TOML at all: file and line
    let e = ix.open_toml_line("fps", "fps = = 25").map(|_| ()).unwrap_err();
    assert!(e.contains(&format!("session.toml:{}", ix.line_of("fps"))), "{e}");
    // a missing field is named
    let toml: String = ix.toml.lines().filter(|l| !l.starts_with("stereo =")).map(|l| format!("{l}\n")).collect();
    let e = ix.open(&toml, &ix.frames).map(|_| ()).unwrap_err();
    assert!(e.contains("session.toml") && e.contains("missing field `stereo`"), "{e}");
}

#[test]
fn paths_that_leave_the_session_are_refused() {
    let ix = Index::new();
    for (key, line, what) in [
        ("stereo", "stereo = \"../elsewhere/stereo.yaml\"", "leaves its directory"),
        ("stereo", "stereo = \"/etc/abvs/stereo.yaml\"", "is absolute"),
        ("stereo", "stereo = \"\"", "empty path"),
        ("poses", "poses = \"truth/../../poses.csv\"", "leaves its directory"),
    ] {
        let e = ix.open_toml_line(key, line).map(|_| ()).unwrap_err();
        let field = if key == "poses" { "truth.poses" } else { key };
        assert_names(&e, &format!("session.toml:{}", ix.line_of(key)), field, what);
    }
    let toml = ix.toml.replace("\"calib/eye1\"", "\"/home/x/eye1\"");
    let e = ix.open(&toml, &ix.frames).map(|_| ()).unwrap_err();
    assert_names(&e, &format!("session.toml:{}", ix.line_of("fk")), "fk", "is absolute");
    // a frame file outside the session: frames.csv and its line
    let frames = ix.frames.replace("frames/left_000007.png", "../../left_000007.png");
    let e = ix.open(&ix.toml, &frames).map(|_| ()).unwrap_err();
    assert!(e.contains("frames.csv:9") && e.contains("left: path `../../left_000007.png` leaves"), "{e}");
}

#[test]
fn bad_frames_csv_rows_name_file_and_line() {
    let ix = Index::new();
    let lines: Vec<&str> = ix.frames.lines().collect();
    // a row cut short (a recording that stopped mid-write): line 6 holds seq 4
    let mut cut = lines.clone();
    cut[5] = &lines[5][..lines[5].len() / 2];
    let e = ix.open(&ix.toml, &(cut.join("\n") + "\n")).map(|_| ()).unwrap_err();
    assert!(e.contains("frames.csv:6") && e.contains("fields, expected 5"), "{e}");
    // the last row cut short, without its newline
    let text = ix.frames.trim_end();
    let e = ix.open(&ix.toml, &text[..text.len() - 30]).map(|_| ()).unwrap_err();
    assert!(e.contains(&format!("frames.csv:{}", lines.len())) && e.contains("fields"), "{e}");
    // a value that is not a number: the column is named
    let bad = ix.frames.replace("7,1263000000,", "7,12630O0000,");
    assert_ne!(bad, ix.frames);
    let e = ix.open(&ix.toml, &bad).map(|_| ()).unwrap_err();
    assert!(e.contains("frames.csv:9") && e.contains("field `t_start_ns`"), "{e}");
    // a seq used twice: frames are matched by seq, so it must identify its row
    let dup = ix.frames.replace("\n8,", "\n7,");
    let e = ix.open(&ix.toml, &dup).map(|_| ()).unwrap_err();
    assert!(e.contains("frames.csv:10") && e.contains("seq 7 is not after the previous row's 7"), "{e}");
    // exposure out of range
    // (0 is an instant, which rendered sessions without blur use; a negative exposure is not)
    let exp = ix.frames.replace("3,1103000000,4000000,", "3,1103000000,-1,");
    let e = ix.open(&ix.toml, &exp).map(|_| ()).unwrap_err();
    assert!(e.contains("frames.csv:5") && e.contains("exposure_ns -1 is out of range"), "{e}");
    // a negative time
    let neg = ix.frames.replace("0,983000000,", "0,-983000000,");
    let e = ix.open(&ix.toml, &neg).map(|_| ()).unwrap_err();
    assert!(e.contains("frames.csv:2") && e.contains("t_start_ns -983000000 is out of range"), "{e}");
}

/// Applies byte edits (replace, remove, insert, cut) at positions taken modulo the length.
fn mutate(mut b: Vec<u8>, edits: &[(usize, u8, u8)]) -> Vec<u8> {
    for &(at, kind, v) in edits {
        if b.is_empty() {
            b.push(v);
            continue;
        }
        let i = at % b.len();
        match kind % 4 {
            0 => b[i] = v,
            1 => {
                b.remove(i);
            }
            2 => b.insert(i, v),
            _ => b.truncate(i),
        }
    }
    b
}

mod fuzz {
    use super::*;
    use proptest::prelude::*;

    fn open_bytes(ix: &Index, toml: &[u8], frames: &[u8]) -> Result<Session, String> {
        std::fs::write(ix.dir.path().join("session.toml"), toml).unwrap();
        std::fs::write(ix.dir.path().join("frames.csv"), frames).unwrap();
        Session::open(ix.dir.path()).map_err(|e| e.to_string())
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 300, ..ProptestConfig::default() })]

        /// Mutated session.toml and frames.csv: the session opens or an error names the file, never a panic.
        #[test]
        fn mutated_index_files_never_panic(
            toml_edits in proptest::collection::vec((any::<usize>(), any::<u8>(), any::<u8>()), 0..5),
            frame_edits in proptest::collection::vec((any::<usize>(), any::<u8>(), any::<u8>()), 0..5),
        ) {
            let ix = Index::new();
            let toml = mutate(ix.toml.clone().into_bytes(), &toml_edits);
            let frames = mutate(ix.frames.clone().into_bytes(), &frame_edits);
            match open_bytes(&ix, &toml, &frames) {
                Ok(s) => {
                    // whatever opened is usable: paths inside, sizes in range
                    prop_assert!(s.meta.width > 0 && s.meta.height > 0 && s.meta.fps > 0.0);
                    let inside = |p: &str| {
                        use std::path::Component;
                        Path::new(p).components().all(|c| matches!(c, Component::Normal(_) | Component::CurDir))
                    };
                    prop_assert!(s.frames.iter().all(|f| inside(&f.left) && inside(&f.right)));
                }
                Err(e) => prop_assert!(e.contains("session.toml") || e.contains("frames.csv"), "{}", e),
            }
        }

        /// Random text in session.toml.
        #[test]
        fn random_session_toml_never_panics(text in "[a-z_ =\"\\[\\]0-9.,\\n-]{0,200}") {
            let ix = Index::new();
            let e = open_bytes(&ix, text.as_bytes(), ix.frames.as_bytes()).map(|_| ()).unwrap_err();
            prop_assert!(e.contains("session.toml"), "{}", e);
        }
    }
}
