//! Writes a recorded session (the format of [`abvs_runtime_core::session`]) as it is captured: frame PNGs and
//! rows of frames.csv and encoders.csv appended and flushed as they come, so that a recording cut
//! short (power, Ctrl-C) keeps everything up to its last second and still opens as a session.
//!
//! A write that fails (a full disk) leaves nothing half-written: a frame file that could not be written
//! is removed and its pair gets no frames.csv row; index rows are appended whole or not at all (a failed
//! append cuts the file back to its last complete row). The error is returned for the caller to count,
//! and later writes are tried again (space may come back); what was written stays a valid session.
use std::fs::File;
use std::io::{Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use abvs_camera::StereoCalibration;

use crate::tasks::kinematics::EyeFk;
use abvs_runtime_core::error::{Result, RuntimeError};
use abvs_runtime_core::messages::{Frame, FramePair};
use abvs_runtime_core::session::{EncoderRecord, FrameRecord, Session, SessionMeta, SESSION_FILE, SESSION_FORMAT};

/// The calibration a recording is made with: copied into the session's calib/.
#[derive(Debug, Clone)]
pub struct CalibFiles {
    /// OpenCV-style stereo calibration at home (abvs-camera YAML).
    pub stereo: PathBuf,
    /// Per-eye FK: an abvs-fk-model directory or a unit-model TOML, left then right.
    pub fk: [PathBuf; 2],
}

impl CalibFiles {
    /// The layout `abvs calib` and `abvs sim session` produce: DIR/stereo.yaml, DIR/eye0, DIR/eye1.
    pub fn from_dir(dir: &Path) -> CalibFiles {
        CalibFiles { stereo: dir.join("stereo.yaml"), fk: [dir.join("eye0"), dir.join("eye1")] }
    }

    /// Loads every file, so a recording never starts with a calibration the runtime cannot use.
    pub fn check(&self) -> Result<()> {
        StereoCalibration::read_yaml(&self.stereo)
            .map_err(|e| RuntimeError::Model { path: self.stereo.clone(), msg: e.to_string() })?;
        for p in &self.fk {
            EyeFk::load(p)?;
        }
        Ok(())
    }
}

fn io_err(path: &Path, e: impl std::fmt::Display) -> RuntimeError {
    RuntimeError::File { path: path.to_path_buf(), line: None, msg: e.to_string() }
}

fn copy_tree(from: &Path, to: &Path) -> std::io::Result<()> {
    if from.is_dir() {
        std::fs::create_dir_all(to)?;
        for e in std::fs::read_dir(from)? {
            let e = e?;
            copy_tree(&e.path(), &to.join(e.file_name()))?;
        }
        Ok(())
    } else {
        std::fs::copy(from, to).map(|_| ())
    }
}

/// 8-bit gray PNG straight from the frame buffer, fast compression (25 fps of two eyes on a robot CPU).
fn write_png(p: &Path, f: &Frame) -> Result<()> {
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    use image::ImageEncoder;
    if f.gray.len() != f.width as usize * f.height as usize {
        return Err(io_err(p, format!("frame buffer of {} bytes for {}x{}", f.gray.len(), f.width, f.height)));
    }
    let w = std::io::BufWriter::new(File::create(p).map_err(|e| io_err(p, e))?);
    PngEncoder::new_with_quality(w, CompressionType::Fast, FilterType::Adaptive)
        .write_image(&f.gray, f.width, f.height, image::ExtendedColorType::L8)
        .map_err(|e| io_err(p, e))
}

/// An index file (frames.csv, encoders.csv) appended a batch of rows at a time, whole or not at all.
struct IndexFile {
    path: PathBuf,
    file: File,
    /// Length of the file up to its last complete row (0: not even the header yet).
    committed: u64,
}

impl IndexFile {
    fn create(path: PathBuf) -> Result<IndexFile> {
        let file = File::create(&path).map_err(|e| io_err(&path, e))?;
        Ok(IndexFile { path, file, committed: 0 })
    }

    fn append<T: serde::Serialize>(&mut self, rows: &[T]) -> Result<()> {
        // the rows (and the header, with the first ones) in memory first, then to the file in one piece
        let mut w = csv::WriterBuilder::new().has_headers(self.committed == 0).from_writer(Vec::new());
        for r in rows {
            w.serialize(r).map_err(|e| io_err(&self.path, e))?;
        }
        let bytes = w.into_inner().map_err(|e| io_err(&self.path, e.error()))?;
        match self.file.write_all(&bytes).and_then(|()| self.file.flush()) {
            Ok(()) => {
                self.committed += bytes.len() as u64;
                Ok(())
            }
            Err(e) => {
                // cut back to the last complete row: the file stays readable, these rows are not written
                let _ = self.file.set_len(self.committed);
                let _ = self.file.seek(SeekFrom::Start(self.committed));
                Err(io_err(&self.path, e))
            }
        }
    }
}

/// An open recording.
pub struct SessionWriter {
    dir: PathBuf,
    meta: SessionMeta,
    meta_written: bool,
    frames_csv: IndexFile,
    encoders_csv: IndexFile,
    last_frame_t: Option<i64>,
    /// Frame pairs written.
    pub frames_written: u64,
    /// Encoder rows written.
    pub encoder_rows: u64,
}

impl SessionWriter {
    /// Creates `dir` (which must not exist, or be empty: a recording never overwrites another)
    /// and copies the calibration in, after checking that it loads.
    pub fn create(dir: &Path, calib: &CalibFiles, fps: f64, description: String) -> Result<SessionWriter> {
        Self::check_target(dir)?;
        if !(fps > 0.0) {
            return Err(RuntimeError::Invalid(format!("frame rate {fps} must be positive")));
        }
        calib.check()?;
        std::fs::create_dir_all(dir.join("frames")).map_err(|e| io_err(dir, e))?;
        std::fs::create_dir_all(dir.join("calib")).map_err(|e| io_err(dir, e))?;
        let sp = dir.join("calib/stereo.yaml");
        std::fs::copy(&calib.stereo, &sp).map_err(|e| io_err(&calib.stereo, e))?;
        let mut fk = [String::new(), String::new()];
        for (eye, src) in calib.fk.iter().enumerate() {
            let ext = if src.is_dir() { String::new() } else { ".toml".into() };
            let rel = format!("calib/eye{eye}{ext}");
            copy_tree(src, &dir.join(&rel)).map_err(|e| io_err(src, e))?;
            fk[eye] = rel;
        }
        let csv_at = |name: &str| IndexFile::create(dir.join(name));
        let meta = SessionMeta {
            format: SESSION_FORMAT.into(),
            description,
            width: 0,
            height: 0,
            fps,
            loop_period_ns: None,
            readout_ms: 0.0,
            exposure_ms: None,
            time_offset_ms: None,
            stereo: "calib/stereo.yaml".into(),
            fk,
            gravity: [0.0, 1.0, 0.0],
            truth: None,
        };
        Ok(SessionWriter {
            dir: dir.to_path_buf(),
            meta,
            meta_written: false,
            frames_csv: csv_at("frames.csv")?,
            encoders_csv: csv_at("encoders.csv")?,
            last_frame_t: None,
            frames_written: 0,
            encoder_rows: 0,
        })
    }

    /// The cameras' rolling-shutter readout (ms) and nominal exposure, recorded in session.toml so a replay
    /// corrects each row as the live run did.
    pub fn with_timing(mut self, readout_ms: f64, exposure_ms: Option<f64>) -> SessionWriter {
        self.meta.readout_ms = readout_ms;
        self.meta.exposure_ms = exposure_ms;
        self
    }

    /// Refuses a directory that exists and is not empty.
    pub fn check_target(dir: &Path) -> Result<()> {
        if dir.exists() && std::fs::read_dir(dir).map_err(|e| io_err(dir, e))?.next().is_some() {
            return Err(io_err(dir, "exists and is not empty (a recording never overwrites another)"));
        }
        Ok(())
    }

    /// The session directory being written.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Writes both images and the pair's frames.csv row. The first pair fixes the frame size and
    /// writes session.toml. Pairs must come in time order (as a capture delivers them).
    pub fn write_pair(&mut self, pair: &FramePair) -> Result<()> {
        let (l, r) = (&pair.left, &pair.right);
        if (l.width, l.height) != (r.width, r.height) {
            return Err(RuntimeError::Invalid(format!(
                "pair {}: left {}x{} and right {}x{} differ",
                pair.seq, l.width, l.height, r.width, r.height
            )));
        }
        if self.last_frame_t.is_some_and(|t| l.t_start_ns <= t) {
            return Err(RuntimeError::Invalid(format!(
                "pair {}: start of exposure not after the previous pair's",
                pair.seq
            )));
        }
        if !self.meta_written {
            self.meta.width = l.width;
            self.meta.height = l.height;
            let mp = self.dir.join(SESSION_FILE);
            let text = toml::to_string_pretty(&self.meta).map_err(|e| io_err(&mp, e))?;
            std::fs::write(&mp, text).map_err(|e| io_err(&mp, e))?;
            self.meta_written = true;
        } else if (l.width, l.height) != (self.meta.width, self.meta.height) {
            return Err(RuntimeError::Invalid(format!(
                "pair {}: frame size {}x{} differs from the session's {}x{}",
                pair.seq, l.width, l.height, self.meta.width, self.meta.height
            )));
        }
        let mut names = [String::new(), String::new()];
        for (k, (f, side)) in [(l, "left"), (r, "right")].into_iter().enumerate() {
            let name = format!("frames/{side}_{:06}.png", self.frames_written);
            let p = self.dir.join(&name);
            if let Err(e) = write_png(&p, f) {
                // no partial file left behind, nor the other eye's of this pair (they would hold space, and
                // look like frames)
                let _ = std::fs::remove_file(&p);
                if k == 1 {
                    let _ = std::fs::remove_file(self.dir.join(&names[0]));
                }
                return Err(e);
            }
            names[k] = name;
        }
        let [left, right] = names;
        let row =
            FrameRecord { seq: self.frames_written, t_start_ns: l.t_start_ns, exposure_ns: l.exposure_ns, left, right };
        self.frames_csv.append(std::slice::from_ref(&row))?;
        self.last_frame_t = Some(l.t_start_ns);
        self.frames_written += 1;
        Ok(())
    }

    /// Appends encoder rows to encoders.csv.
    pub fn write_encoders(&mut self, rows: &[EncoderRecord]) -> Result<()> {
        self.encoders_csv.append(rows)?;
        self.encoder_rows += rows.len() as u64;
        Ok(())
    }

    /// Flushes and checks that the result opens as a session.
    pub fn finish(self) -> Result<Session> {
        // (the index files hold only complete rows: nothing is buffered)
        if !self.meta_written {
            return Err(io_err(&self.dir, "no frame pair was recorded"));
        }
        Session::open(&self.dir)
    }
}
