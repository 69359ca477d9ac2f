//! Gaze scripts: timed goals for the simulated head (`abvs run --source sim --gaze-script FILE`, tests, demos).
//!
//! One goal per line, fields separated by white space; `#` starts a comment; blank lines are skipped:
//!
//! ```text
//! # at_ms  kind     x     y     z     [vx   vy   vz]
//! 100      look_at  0.10  -0.05 0.80
//! 600      pursue   -0.20 0.00  1.00  0.35 0.00 0.00
//! 1400     hold
//! 1600     home
//! ```
//!
//! - `at_ms`: virtual time from the first frame's instant (ms, finite, >= 0, not before the previous line's);
//!   the goal is posted at the first frame whose instant is at or after it, and taken by the controller at
//!   that frame.
//! - `kind`: `look_at` (x y z), `pursue` (x y z vx vy vz), `hold`, `home` (no numbers).
//! - Points in metres and velocities in m/s, in the left home camera frame (x right, y down, z forward).
//!   Numbers are Rust `f64` literals: `nan` and `inf` are read as such, on purpose, so that a script can
//!   test the controller's refusals (the goal is refused by name, the eyes do not move).
//!
//! A line that cannot be read is an error naming the file, the line and the field.
use std::path::{Path, PathBuf};

use abvs_runtime::gaze::GazeHandle;
use abvs_runtime_core::error::{Result, RuntimeError};

/// What a goal asks for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ScriptKind {
    LookAt([f64; 3]),
    Pursue([f64; 3], [f64; 3]),
    Hold,
    Home,
}

/// One timed goal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScriptGoal {
    /// Virtual time from the first frame's instant (ms).
    pub at_ms: f64,
    pub kind: ScriptKind,
    /// The line it came from (1-based).
    pub line: usize,
}

impl ScriptGoal {
    /// Posts the goal through `h`; returns its id.
    pub fn post(&self, h: &GazeHandle) -> u64 {
        match self.kind {
            ScriptKind::LookAt(p) => h.look_at(p),
            ScriptKind::Pursue(p, v) => h.pursue(p, v),
            ScriptKind::Hold => h.hold(),
            ScriptKind::Home => h.home(),
        }
    }
}

/// A parsed script, goals in time order.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct GazeScript {
    pub goals: Vec<ScriptGoal>,
}

const FIELDS: [&str; 6] = ["x", "y", "z", "vx", "vy", "vz"];

impl GazeScript {
    /// Reads a script file.
    pub fn load(path: &Path) -> Result<GazeScript> {
        let text = std::fs::read_to_string(path).map_err(|e| RuntimeError::File {
            path: path.to_path_buf(),
            line: None,
            msg: format!("reading the gaze script: {e}"),
        })?;
        Self::parse(&text, path)
    }

    /// Parses a script's text; errors name `origin`, the line and the field.
    pub fn parse(text: &str, origin: &Path) -> Result<GazeScript> {
        let mut goals: Vec<ScriptGoal> = Vec::new();
        for (i, raw) in text.lines().enumerate() {
            let line = i + 1;
            let err = |msg: String| RuntimeError::File { path: PathBuf::from(origin), line: Some(line as u64), msg };
            let content = raw.split('#').next().unwrap_or("");
            let cols: Vec<&str> = content.split_whitespace().collect();
            if cols.is_empty() {
                continue;
            }
            let at_ms: f64 = cols[0].parse().map_err(|_| err(format!("field at_ms: `{}` is not a number", cols[0])))?;
            if !(at_ms.is_finite() && at_ms >= 0.0) {
                return Err(err(format!("field at_ms: {at_ms} must be finite and >= 0")));
            }
            if let Some(prev) = goals.last() {
                if at_ms < prev.at_ms {
                    return Err(err(format!(
                        "field at_ms: {at_ms} is before line {}'s {} (goals in time order)",
                        prev.line, prev.at_ms
                    )));
                }
            }
            let Some(kind) = cols.get(1) else {
                return Err(err("field kind: missing (look_at, pursue, hold or home)".into()));
            };
            let want = match *kind {
                "look_at" => 3,
                "pursue" => 6,
                "hold" | "home" => 0,
                k => return Err(err(format!("field kind: `{k}` is not look_at, pursue, hold or home"))),
            };
            let nums = &cols[2..];
            if nums.len() != want {
                let names = FIELDS[..want].join(" ");
                return Err(err(format!(
                    "{kind} takes {want} numbers{}{names}, found {}",
                    if want > 0 { ": " } else { "" },
                    nums.len()
                )));
            }
            let mut v = [0.0; 6];
            for (k, c) in nums.iter().enumerate() {
                v[k] = c.parse().map_err(|_| err(format!("field {}: `{c}` is not a number", FIELDS[k])))?;
            }
            let kind = match *kind {
                "look_at" => ScriptKind::LookAt([v[0], v[1], v[2]]),
                "pursue" => ScriptKind::Pursue([v[0], v[1], v[2]], [v[3], v[4], v[5]]),
                "hold" => ScriptKind::Hold,
                _ => ScriptKind::Home,
            };
            goals.push(ScriptGoal { at_ms, kind, line });
        }
        Ok(GazeScript { goals })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn reads_every_kind_and_names_bad_lines() {
        let s = GazeScript::parse(
            "# demo\n100 look_at 0.1 -0.05 0.8\n\n600 pursue -0.2 0 1 0.35 0 0 # right\n1400 hold\n1600 home\n\
             1700 look_at nan 0 1\n",
            Path::new("g.txt"),
        )
        .unwrap();
        assert_eq!(s.goals.len(), 5);
        assert_eq!(s.goals[0], ScriptGoal { at_ms: 100.0, kind: ScriptKind::LookAt([0.1, -0.05, 0.8]), line: 2 });
        assert_eq!(s.goals[1].kind, ScriptKind::Pursue([-0.2, 0.0, 1.0], [0.35, 0.0, 0.0]));
        assert_eq!((s.goals[2].kind, s.goals[3].kind), (ScriptKind::Hold, ScriptKind::Home));
        // a NaN point is a goal (the controller refuses it by name), not a parse error
        assert!(matches!(s.goals[4].kind, ScriptKind::LookAt(p) if p[0].is_nan()));
        for (text, line, field) in [
            ("1 look_at 0 0\n", 1, "look_at takes 3"),
            ("\n\nx look_at 0 0 1\n", 3, "field at_ms"),
            ("5 look_at 0 0 1\n4 hold\n", 2, "field at_ms: 4 is before line 1"),
            ("1 stare 0 0 1\n", 1, "field kind: `stare`"),
            ("1\n", 1, "field kind: missing"),
            ("1 pursue 0 0 1 0 zero 0\n", 1, "field vy: `zero`"),
            ("-1 hold\n", 1, "field at_ms: -1"),
            ("inf hold\n", 1, "field at_ms: inf"),
            ("1 home 3\n", 1, "home takes 0"),
        ] {
            let e = GazeScript::parse(text, Path::new("g.txt")).unwrap_err().to_string();
            assert!(e.contains(&format!("g.txt:{line}")) && e.contains(field), "{text:?}: {e}");
        }
    }

    #[test]
    fn random_lines_parse_or_fail_with_the_line_never_panic() {
        let words =
            ["0", "12.5", "-3", "nan", "inf", "1e308", "look_at", "pursue", "hold", "home", "#", "x", "", "\u{e9}"];
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for _ in 0..3000 {
            let n = rng.gen_range(0..9);
            let line: Vec<&str> = (0..n).map(|_| words[rng.gen_range(0..words.len())]).collect();
            let text = format!("# head\n{}\n", line.join(" "));
            match GazeScript::parse(&text, Path::new("f.txt")) {
                Ok(s) => assert!(s.goals.len() <= 1 && s.goals.iter().all(|g| g.line == 2 && g.at_ms >= 0.0)),
                Err(e) => assert!(e.to_string().contains("f.txt:2"), "{text:?}: {e}"),
            }
        }
    }
}
