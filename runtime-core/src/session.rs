//! Recorded sessions: the on-disk format `abvs record` writes from live sources, `abvs sim session` renders
//! from the simulator, and the replay source reads.
//!
//! ```text
//! <dir>/session.toml     format = "abvs-session/1"; frame size, rate, exposure; calibration and truth paths
//! <dir>/frames.csv       seq,t_start_ns,exposure_ns,left,right     (one row per stereo pair, paths relative)
//! <dir>/frames/*.png     8-bit gray raw (distorted) images at the session's frame size
//! <dir>/encoders.csv     t_ns,eye,count1,count2,count3             (homed counts, CLOCK_MONOTONIC stamps)
//! <dir>/calib/stereo.yaml  intrinsics of both eyes + T_lH^rH (abvs-camera's OpenCV YAML)
//! <dir>/calib/eye0|eye1    per-eye FK: an abvs-fk-model directory (calibrated) ...
//! <dir>/truth/...          synthetic sessions only: true unit models, true poses per frame, the scene
//! ```
//! Counts are relative to each link's home (theta = 360 * count / 92672 deg, conventions.md), stamped with the
//! drive board's time already mapped to CLOCK_MONOTONIC; timestamps of both files share that clock.
//! Every reader error names the file and line, and for session.toml the field: a bad TOML type, a value out
//! of range (a size, rate or loop period that is not positive, a gravity that is not a unit vector), a
//! truncated or malformed CSV row, rows out of order. Every path a session names (calibration, truth, frame
//! files) is relative and stays inside the session directory: absolute paths and `..` are refused.
use std::ops::Range;
use std::path::{Component, Path, PathBuf};

use abvs_eye::encoder::COUNTS_PER_REV;
use serde::{Deserialize, Serialize};
use toml::Spanned;

use crate::error::{Result, RuntimeError};
use crate::messages::EncoderSample;

/// An encoder_time_offset setting (ms: the encoder stream is stamped this much late; effects.md): one value
/// for both eyes (`time_offset_ms = 2.0`) or one per eye, left then right (`time_offset_ms = [2.0, 2.4]`).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(untagged)]
pub enum TimeOffsetMs {
    /// The same offset for both eyes (one drive board stamps both).
    Both(f64),
    /// Left, right.
    PerEye([f64; 2]),
}

impl TimeOffsetMs {
    /// Left and right offsets (ms).
    pub fn per_eye(&self) -> [f64; 2] {
        match *self {
            TimeOffsetMs::Both(t) => [t, t],
            TimeOffsetMs::PerEye(t) => t,
        }
    }

    /// Refuses an offset beyond a second (or NaN), naming `field`.
    #[allow(clippy::neg_cmp_op_on_partial_ord)] // refuses NaN too
    pub fn check(&self, field: &str) -> std::result::Result<(), String> {
        match self.per_eye().into_iter().find(|t| !(t.abs() <= 1000.0)) {
            Some(t) => Err(format!("{field}: {t} must be in [-1000, 1000] ms")),
            None => Ok(()),
        }
    }
}

/// The format tag of session.toml.
pub const SESSION_FORMAT: &str = "abvs-session/1";
/// The session's metadata file, in its directory.
pub const SESSION_FILE: &str = "session.toml";

/// Largest frame width or height a session may declare (pixels): the pipeline allocates its buffers from it.
pub const MAX_FRAME_SIDE: u32 = 16384;
/// Highest frame rate a session may declare (Hz).
pub const MAX_FPS: f64 = 1000.0;
/// Longest exposure of a frame (ns).
pub const MAX_EXPOSURE_NS: i64 = 1_000_000_000;
/// Timestamps (ns) must lie in [0, MAX_T_NS): CLOCK_MONOTONIC values, far from overflow when shifted.
pub const MAX_T_NS: i64 = 1 << 60;

/// Checks a path read from a session or a model manifest: relative to that file's directory and inside it.
/// Refuses an empty path, an absolute path and any `..` component (the check is on the text: a symbolic
/// link inside the directory is followed).
pub fn check_inside(rel: &str) -> std::result::Result<(), String> {
    if rel.is_empty() {
        return Err("empty path".into());
    }
    for c in Path::new(rel).components() {
        match c {
            Component::Normal(_) | Component::CurDir => {}
            Component::ParentDir => return Err(format!("path `{rel}` leaves its directory (`..`)")),
            Component::RootDir | Component::Prefix(_) => {
                return Err(format!("path `{rel}` is absolute (paths are relative to their directory)"))
            }
        }
    }
    Ok(())
}

/// session.toml
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SessionMeta {
    /// The format tag, [`SESSION_FORMAT`].
    pub format: String,
    /// Free text: where the session comes from.
    #[serde(default)]
    pub description: String,
    /// Frame width (px, both eyes).
    pub width: u32,
    /// Frame height (px).
    pub height: u32,
    /// Frame rate the session was recorded at (Hz).
    pub fps: f64,
    /// Duration of one loop when the recording is periodic (synthetic sessions): a looped replay shifts by
    /// exactly this, so motion continues seamlessly. Without it a loop lasts from the first to the last
    /// timestamp plus one frame period.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub loop_period_ns: Option<i64>,
    /// Rolling-shutter readout (ms): from the first row's start of exposure to the last row's
    /// (conventions.md "Time"); 0 = a global shutter (and sessions written before it was recorded).
    #[serde(default)]
    pub readout_ms: f64,
    /// The nominal exposure (ms), for people; frames.csv holds each frame's own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exposure_ms: Option<f64>,
    /// The encoders' encoder_time_offset (ms; one value or `[left, right]`) where it was measured (`abvs calib
    /// self-check --session`): a replay applies it instead of the FK models'.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time_offset_ms: Option<TimeOffsetMs>,
    /// Stereo calibration at home (relative path).
    pub stereo: String,
    /// Per-eye FK model directories or unit-model TOML files (relative paths), left then right.
    pub fk: [String; 2],
    /// Gravity direction in each eye's base frame (for gravity_sag), unit vector.
    #[serde(default = "default_gravity")]
    pub gravity: [f64; 3],
    /// Present for synthetic sessions.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub truth: Option<Truth>,
}

fn default_gravity() -> [f64; 3] {
    [0.0, 1.0, 0.0]
}

/// Ground truth of a synthetic session.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Truth {
    /// True unit models (TOML), left then right.
    pub units: [String; 2],
    /// The scene generator and its seed: the scene is rebuilt from them (exact geometry, no mesh files).
    pub scene_generator: String,
    /// The scene generator's seed.
    pub scene_seed: u64,
    /// The true stereo calibration at home (the one in `stereo` may be an estimate).
    pub stereo: String,
    /// Per-frame true link angles of both eyes at the frame's instant, its middle row's mid-exposure (CSV:
    /// seq, l1,l2,l3, r1,r2,r3 in deg).
    pub poses: String,
    /// Rolling-shutter sessions: true link angles at row nodes (CSV: seq, node, l1,l2,l3, r1,r2,r3; node n of
    /// N at row n (H - 1) / N, that row's mid-exposure), for scoring where each raw row really looked.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub row_poses: Option<String>,
}

/// One row of frames.csv.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameRecord {
    /// The frame pair's sequence number.
    pub seq: u64,
    /// Start of exposure of the left frame's first row (ns, the session's clock).
    pub t_start_ns: i64,
    /// Exposure time (ns).
    pub exposure_ns: i64,
    /// Left frame file, relative to the session directory.
    pub left: String,
    /// Right frame file.
    pub right: String,
}

/// One row of encoders.csv.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EncoderRecord {
    /// The sample's time (ns, the session's clock).
    pub t_ns: i64,
    /// Which eye: 0 left, 1 right.
    pub eye: u8,
    /// Homed count of link 1.
    pub count1: i64,
    /// Homed count of link 2.
    pub count2: i64,
    /// Homed count of link 3.
    pub count3: i64,
}

impl EncoderRecord {
    /// The sample in seconds and degrees.
    pub fn sample(&self) -> EncoderSample {
        let deg = |c: i64| c as f64 * 360.0 / COUNTS_PER_REV as f64;
        EncoderSample {
            t_s: self.t_ns as f64 * 1e-9,
            theta_deg: [deg(self.count1), deg(self.count2), deg(self.count3)],
        }
    }
}

/// A session directory, its metadata and its index files (frames are read on demand).
#[derive(Debug, Clone)]
pub struct Session {
    /// The session directory.
    pub dir: PathBuf,
    /// session.toml.
    pub meta: SessionMeta,
    /// frames.csv, in order.
    pub frames: Vec<FrameRecord>,
    /// encoders.csv, in file order.
    pub encoders: Vec<EncoderRecord>,
}

fn io_err(path: &Path, e: impl std::fmt::Display) -> RuntimeError {
    RuntimeError::File { path: path.to_path_buf(), line: None, msg: e.to_string() }
}

fn line_err(path: &Path, line: u64, msg: impl std::fmt::Display) -> RuntimeError {
    RuntimeError::File { path: path.to_path_buf(), line: Some(line), msg: msg.to_string() }
}

impl Session {
    /// Reads session.toml and the index files (frames.csv, encoders.csv) of the session in `dir`; frames are read on demand.
    pub fn open(dir: &Path) -> Result<Session> {
        let mp = dir.join(SESSION_FILE);
        let text = std::fs::read_to_string(&mp).map_err(|e| io_err(&mp, e))?;
        let (meta, spans) = parse_meta(&mp, &text)?;
        let frames = read_frames(&dir.join("frames.csv"))?;
        let encoders = read_encoders(&dir.join("encoders.csv"))?;
        if let Some(period) = meta.loop_period_ns {
            // a looped replay shifts every time by the period: it must exceed each stream's span, or
            // timestamps would go back at the seam
            let span = |t: &mut dyn Iterator<Item = i64>| {
                let (lo, hi) = t.fold((i64::MAX, i64::MIN), |(lo, hi), x| (lo.min(x), hi.max(x)));
                hi - lo
            };
            let fs = span(&mut frames.iter().map(|f| f.t_start_ns));
            let es = (0..2u8).map(|e| span(&mut encoders.iter().filter(|r| r.eye == e).map(|r| r.t_ns))).max();
            for (what, s) in [("frames.csv", fs), ("encoders.csv", es.unwrap_or(0))] {
                if period <= s {
                    return Err(field_err(
                        &mp,
                        &text,
                        spans.loop_period_ns.as_ref().map(Spanned::span),
                        "loop_period_ns",
                        format!(
                            "{period} ns is not longer than the {s} ns {what} spans (looped timestamps would go back)"
                        ),
                    ));
                }
            }
        }
        Ok(Session { dir: dir.to_path_buf(), meta, frames, encoders })
    }

    /// A path of the session (relative to its directory).
    pub fn path(&self, rel: &str) -> PathBuf {
        self.dir.join(rel)
    }

    /// Encoder samples of one eye, in file order.
    pub fn encoder_samples(&self, eye: u8) -> Vec<EncoderSample> {
        self.encoders.iter().filter(|r| r.eye == eye).map(EncoderRecord::sample).collect()
    }

    /// Writes session.toml, frames.csv and encoders.csv (the frame images are written by the caller).
    pub fn write_index(
        dir: &Path,
        meta: &SessionMeta,
        frames: &[FrameRecord],
        encoders: &[EncoderRecord],
    ) -> Result<()> {
        std::fs::create_dir_all(dir).map_err(|e| io_err(dir, e))?;
        let mp = dir.join(SESSION_FILE);
        let text = toml::to_string_pretty(meta).map_err(|e| io_err(&mp, e))?;
        std::fs::write(&mp, text).map_err(|e| io_err(&mp, e))?;
        write_csv(&dir.join("frames.csv"), frames)?;
        write_csv(&dir.join("encoders.csv"), encoders)
    }
}

fn write_csv<T: Serialize>(path: &Path, rows: &[T]) -> Result<()> {
    let mut w = csv::Writer::from_path(path).map_err(|e| io_err(path, e))?;
    for r in rows {
        w.serialize(r).map_err(|e| io_err(path, e))?;
    }
    w.flush().map_err(|e| io_err(path, e))
}

/// Line of a byte offset in a text (1-based).
fn line_of(text: &str, offset: usize) -> u64 {
    let end = offset.min(text.len());
    text.as_bytes()[..end].iter().filter(|&&b| b == b'\n').count() as u64 + 1
}

fn field_err(
    path: &Path,
    text: &str,
    span: Option<Range<usize>>,
    field: &str,
    msg: impl std::fmt::Display,
) -> RuntimeError {
    RuntimeError::File {
        path: path.to_path_buf(),
        line: span.map(|s| line_of(text, s.start)),
        msg: format!("`{field}`: {msg}"),
    }
}

/// Where each field of session.toml is (for errors), read alongside [`SessionMeta`].
#[derive(Deserialize, Default)]
struct MetaSpans {
    format: Option<Spanned<toml::Value>>,
    width: Option<Spanned<toml::Value>>,
    height: Option<Spanned<toml::Value>>,
    fps: Option<Spanned<toml::Value>>,
    loop_period_ns: Option<Spanned<toml::Value>>,
    readout_ms: Option<Spanned<toml::Value>>,
    exposure_ms: Option<Spanned<toml::Value>>,
    time_offset_ms: Option<Spanned<toml::Value>>,
    stereo: Option<Spanned<toml::Value>>,
    fk: Option<Spanned<toml::Value>>,
    gravity: Option<Spanned<toml::Value>>,
    truth: Option<TruthSpans>,
}

#[derive(Deserialize, Default)]
struct TruthSpans {
    units: Option<Spanned<toml::Value>>,
    stereo: Option<Spanned<toml::Value>>,
    poses: Option<Spanned<toml::Value>>,
    row_poses: Option<Spanned<toml::Value>>,
}

/// The key of a `key = value` line (for a TOML error that points into a value).
fn key_at(text: &str, offset: usize) -> Option<String> {
    let bytes = &text.as_bytes()[..offset.min(text.len())];
    let start = bytes.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
    let line = text.get(start..)?.lines().next()?;
    let (k, _) = line.split_once('=')?;
    let k = k.trim().trim_matches('"');
    (!k.is_empty() && !k.starts_with('[')).then(|| k.to_string())
}

/// Parses and checks session.toml: every error names the file, the line and the field.
fn parse_meta(mp: &Path, text: &str) -> Result<(SessionMeta, MetaSpans)> {
    let meta: SessionMeta = toml::from_str(text).map_err(|e| {
        let span = e.span().filter(|s| s.start < text.len());
        let msg = e.message().trim().to_string();
        match span.as_ref().and_then(|s| key_at(text, s.start)) {
            // (a missing field's span is the whole table: no line to point at)
            Some(k) if !msg.starts_with("missing field") => field_err(mp, text, span, &k, msg),
            _ => RuntimeError::File {
                path: mp.to_path_buf(),
                line: span.filter(|s| s.start > 0).map(|s| line_of(text, s.start)),
                msg,
            },
        }
    })?;
    let spans: MetaSpans = toml::from_str(text).unwrap_or_default();
    let sp = |s: &Option<Spanned<toml::Value>>| s.as_ref().map(Spanned::span);
    let bad = |span: Option<Range<usize>>, field: &str, msg: String| Err(field_err(mp, text, span, field, msg));
    if meta.format != SESSION_FORMAT {
        return bad(sp(&spans.format), "format", format!("`{}`, expected `{SESSION_FORMAT}`", meta.format));
    }
    for (field, v, s) in [("width", meta.width, &spans.width), ("height", meta.height, &spans.height)] {
        if v == 0 || v > MAX_FRAME_SIDE {
            return bad(sp(s), field, format!("{v} is out of range (1 ..= {MAX_FRAME_SIDE} pixels)"));
        }
    }
    if !(meta.fps > 0.0 && meta.fps <= MAX_FPS) {
        return bad(sp(&spans.fps), "fps", format!("{} is out of range (0 < fps <= {MAX_FPS})", meta.fps));
    }
    if let Some(p) = meta.loop_period_ns {
        if p <= 0 || p >= MAX_T_NS {
            return bad(
                sp(&spans.loop_period_ns),
                "loop_period_ns",
                format!("{p} is out of range (a positive duration in ns)"),
            );
        }
    }
    // a readout longer than a frame period would overlap the next frame's first rows
    let frame_ms = 1e3 / meta.fps;
    if !(0.0..=frame_ms).contains(&meta.readout_ms) {
        return bad(
            sp(&spans.readout_ms),
            "readout_ms",
            format!("{} is out of range (0 ..= {frame_ms} ms, one frame period)", meta.readout_ms),
        );
    }
    if let Some(e) = meta.exposure_ms {
        // a row exposes within its frame period (the next frame's row starts one period later)
        let max_ms = frame_ms.min(MAX_EXPOSURE_NS as f64 * 1e-6);
        if !(0.0..=max_ms).contains(&e) {
            return bad(
                sp(&spans.exposure_ms),
                "exposure_ms",
                format!("{e} is out of range (0 ..= {max_ms} ms, at most one frame period)"),
            );
        }
    }
    if let Some(t) = &meta.time_offset_ms {
        if let Err(e) = t.check("time_offset_ms") {
            return bad(sp(&spans.time_offset_ms), "time_offset_ms", e);
        }
    }
    let g = meta.gravity;
    let norm = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
    let unit = norm.is_finite() && (norm - 1.0).abs() <= 1e-3;
    if !unit {
        return bad(sp(&spans.gravity), "gravity", format!("{g:?} is not a unit vector (norm {norm})"));
    }
    let mut paths = vec![("stereo", &meta.stereo, sp(&spans.stereo))];
    paths.extend(meta.fk.iter().map(|p| ("fk", p, sp(&spans.fk))));
    if let Some(t) = &meta.truth {
        let ts = spans.truth.as_ref();
        let tsp = |f: fn(&TruthSpans) -> &Option<Spanned<toml::Value>>| ts.and_then(|t| sp(f(t)));
        paths.extend(t.units.iter().map(|p| ("truth.units", p, tsp(|t| &t.units))));
        paths.push(("truth.stereo", &t.stereo, tsp(|t| &t.stereo)));
        paths.push(("truth.poses", &t.poses, tsp(|t| &t.poses)));
        if let Some(r) = &t.row_poses {
            paths.push(("truth.row_poses", r, tsp(|t| &t.row_poses)));
        }
    }
    for (field, p, span) in paths {
        if let Err(e) = check_inside(p) {
            return bad(span, field, e);
        }
    }
    Ok((meta, spans))
}

/// A CSV error with the line of its record and, for a value that does not parse, the column's name.
fn csv_err(path: &Path, e: &csv::Error, headers: &csv::StringRecord) -> RuntimeError {
    let line = e.position().map(|p| p.line());
    let msg = match e.kind() {
        csv::ErrorKind::UnequalLengths { expected_len, len, .. } => {
            format!("{len} fields, expected {expected_len} (a truncated or malformed row)")
        }
        csv::ErrorKind::Deserialize { err, .. } => match err.field().and_then(|i| headers.get(i as usize)) {
            Some(name) => format!("field `{name}`: {}", err.kind()),
            None => err.kind().to_string(),
        },
        _ => e.to_string(),
    };
    RuntimeError::File { path: path.to_path_buf(), line, msg }
}

/// Reads a CSV file with a header row: each row with its line.
fn read_csv<T: for<'de> Deserialize<'de>>(path: &Path) -> Result<Vec<(u64, T)>> {
    let mut r = csv::Reader::from_path(path).map_err(|e| io_err(path, e))?;
    let headers = r.headers().map_err(|e| csv_err(path, &e, &csv::StringRecord::new()))?.clone();
    let mut out = Vec::new();
    let mut rec = csv::StringRecord::new();
    while r.read_record(&mut rec).map_err(|e| csv_err(path, &e, &headers))? {
        let line = rec.position().map_or(0, |p| p.line());
        let row: T = rec.deserialize(Some(&headers)).map_err(|e| csv_err(path, &e, &headers))?;
        out.push((line, row));
    }
    Ok(out)
}

fn read_frames(path: &Path) -> Result<Vec<FrameRecord>> {
    let rows: Vec<(u64, FrameRecord)> = read_csv(path)?;
    if rows.is_empty() {
        return Err(io_err(path, "no frames"));
    }
    for (i, (line, r)) in rows.iter().enumerate() {
        let bad = |msg: String| Err(line_err(path, *line, msg));
        if !(0..MAX_T_NS).contains(&r.t_start_ns) {
            return bad(format!("t_start_ns {} is out of range (0 .. 2^60 ns)", r.t_start_ns));
        }
        // 0: an instantaneous exposure (rendered sessions without motion blur)
        if r.exposure_ns < 0 || r.exposure_ns > MAX_EXPOSURE_NS {
            return bad(format!("exposure_ns {} is out of range (0 ..= {MAX_EXPOSURE_NS})", r.exposure_ns));
        }
        if i > 0 {
            let prev = &rows[i - 1].1;
            // frames are matched (truth, pipeline seq) by seq: it identifies a row
            if r.seq <= prev.seq {
                return bad(format!("seq {} is not after the previous row's {}", r.seq, prev.seq));
            }
            if r.t_start_ns <= prev.t_start_ns {
                return bad(format!("t_start_ns {} is not after the previous row's {}", r.t_start_ns, prev.t_start_ns));
            }
        }
        for (side, p) in [("left", &r.left), ("right", &r.right)] {
            if let Err(e) = check_inside(p) {
                return bad(format!("{side}: {e}"));
            }
        }
    }
    Ok(rows.into_iter().map(|(_, r)| r).collect())
}

fn read_encoders(path: &Path) -> Result<Vec<EncoderRecord>> {
    let rows: Vec<(u64, EncoderRecord)> = read_csv(path)?;
    for (line, r) in &rows {
        if r.eye > 1 {
            return Err(line_err(path, *line, format!("eye {} (expected 0 = left or 1 = right)", r.eye)));
        }
        if !(0..MAX_T_NS).contains(&r.t_ns) {
            return Err(line_err(path, *line, format!("t_ns {} is out of range (0 .. 2^60 ns)", r.t_ns)));
        }
    }
    for eye in 0..2u8 {
        if !rows.iter().any(|(_, r)| r.eye == eye) {
            return Err(io_err(path, format!("no samples of eye {eye}")));
        }
    }
    Ok(rows.into_iter().map(|(_, r)| r).collect())
}
