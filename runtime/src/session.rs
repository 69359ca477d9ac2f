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
//! Every reader error names the file and line.
use std::path::{Path, PathBuf};

use abvs_eye::encoder::COUNTS_PER_REV;
use serde::{Deserialize, Serialize};

use crate::error::{Result, RuntimeError};
use crate::tasks::align::EncoderSample;

pub const SESSION_FORMAT: &str = "abvs-session/1";
pub const SESSION_FILE: &str = "session.toml";

/// session.toml
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SessionMeta {
    pub format: String,
    /// Free text: where the session comes from.
    #[serde(default)]
    pub description: String,
    pub width: u32,
    pub height: u32,
    pub fps: f64,
    /// Duration of one loop when the recording is periodic (synthetic sessions): a looped replay shifts by
    /// exactly this, so motion continues seamlessly. Without it a loop lasts from the first to the last
    /// timestamp plus one frame period.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub loop_period_ns: Option<i64>,
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
    pub scene_seed: u64,
    /// The true stereo calibration at home (the one in `stereo` may be an estimate).
    pub stereo: String,
    /// Per-frame true link angles of both eyes at mid-exposure (CSV: seq, l1,l2,l3, r1,r2,r3 in deg).
    pub poses: String,
}

/// One row of frames.csv.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameRecord {
    pub seq: u64,
    pub t_start_ns: i64,
    pub exposure_ns: i64,
    pub left: String,
    pub right: String,
}

/// One row of encoders.csv.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EncoderRecord {
    pub t_ns: i64,
    pub eye: u8,
    pub count1: i64,
    pub count2: i64,
    pub count3: i64,
}

impl EncoderRecord {
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
    pub dir: PathBuf,
    pub meta: SessionMeta,
    pub frames: Vec<FrameRecord>,
    pub encoders: Vec<EncoderRecord>,
}

fn io_err(path: &Path, e: impl std::fmt::Display) -> RuntimeError {
    RuntimeError::File { path: path.to_path_buf(), line: None, msg: e.to_string() }
}

fn line_err(path: &Path, line: u64, msg: impl std::fmt::Display) -> RuntimeError {
    RuntimeError::File { path: path.to_path_buf(), line: Some(line), msg: msg.to_string() }
}

impl Session {
    pub fn open(dir: &Path) -> Result<Session> {
        let mp = dir.join(SESSION_FILE);
        let text = std::fs::read_to_string(&mp).map_err(|e| io_err(&mp, e))?;
        let meta: SessionMeta = toml::from_str(&text).map_err(|e| io_err(&mp, e))?;
        if meta.format != SESSION_FORMAT {
            return Err(io_err(&mp, format!("format `{}`, expected `{SESSION_FORMAT}`", meta.format)));
        }
        if meta.width == 0 || meta.height == 0 || !(meta.fps > 0.0) {
            return Err(io_err(&mp, "width, height and fps must be positive"));
        }
        let frames = read_frames(&dir.join("frames.csv"))?;
        let encoders = read_encoders(&dir.join("encoders.csv"))?;
        Ok(Session { dir: dir.to_path_buf(), meta, frames, encoders })
    }

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

fn read_csv<T: for<'de> Deserialize<'de>>(path: &Path) -> Result<Vec<T>> {
    let mut r = csv::Reader::from_path(path).map_err(|e| io_err(path, e))?;
    let mut out = Vec::new();
    for (i, row) in r.deserialize().enumerate() {
        // header is line 1
        out.push(row.map_err(|e: csv::Error| line_err(path, i as u64 + 2, e))?);
    }
    Ok(out)
}

fn read_frames(path: &Path) -> Result<Vec<FrameRecord>> {
    let rows: Vec<FrameRecord> = read_csv(path)?;
    if rows.is_empty() {
        return Err(io_err(path, "no frames"));
    }
    for (i, w) in rows.windows(2).enumerate() {
        if w[1].t_start_ns <= w[0].t_start_ns {
            return Err(line_err(
                path,
                i as u64 + 3,
                format!("t_start_ns {} is not after the previous row's {}", w[1].t_start_ns, w[0].t_start_ns),
            ));
        }
    }
    for (i, r) in rows.iter().enumerate() {
        if r.exposure_ns <= 0 {
            return Err(line_err(path, i as u64 + 2, format!("exposure_ns {} is not positive", r.exposure_ns)));
        }
    }
    Ok(rows)
}

fn read_encoders(path: &Path) -> Result<Vec<EncoderRecord>> {
    let rows: Vec<EncoderRecord> = read_csv(path)?;
    for (i, r) in rows.iter().enumerate() {
        if r.eye > 1 {
            return Err(line_err(path, i as u64 + 2, format!("eye {} (expected 0 = left or 1 = right)", r.eye)));
        }
    }
    for eye in 0..2u8 {
        if !rows.iter().any(|r| r.eye == eye) {
            return Err(io_err(path, format!("no samples of eye {eye}")));
        }
    }
    Ok(rows)
}
