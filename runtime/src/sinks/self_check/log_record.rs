//! The self-check logs' records: one struct per line kind, used by the writer (the self-check's worker) and
//! by every reader (`abvs calib self-check`, `abvs_selfcheck`, tests). The column names are the fields' names
//! and the number formats are the fields' serde attributes, so a column is named in one place.
//!
//! Plain data (serde, csv): no runtime type appears here, so the module can sit in a crate below the runtime.
//!
//! Numbers: `f64` fields are written with a fixed number of decimals; a field marked "empty when not finite"
//! is written empty for NaN (no fit, no timing context). The frame log's `f64` fields read an empty value as
//! NaN, the match log's must be finite numbers; a column that older logs lack reads as NaN or `None` (marked
//! per field).
use std::path::{Path, PathBuf};

use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// One line of the per-frame log (`--self-check-log FILE`): a checked frame.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct FrameRecord {
    /// The frame's pipeline sequence number.
    pub seq: u64,
    /// The frame's instant (CLOCK_MONOTONIC ns).
    pub t_ns: i64,
    /// Left eye's link 1 angle (deg).
    #[serde(serialize_with = "fixed6", deserialize_with = "number")]
    pub l1_deg: f64,
    /// Left eye's link 2 angle (deg).
    #[serde(serialize_with = "fixed6", deserialize_with = "number")]
    pub l2_deg: f64,
    /// Left eye's link 3 angle (deg).
    #[serde(serialize_with = "fixed6", deserialize_with = "number")]
    pub l3_deg: f64,
    /// Right eye's link 1 angle (deg).
    #[serde(serialize_with = "fixed6", deserialize_with = "number")]
    pub r1_deg: f64,
    /// Right eye's link 2 angle (deg).
    #[serde(serialize_with = "fixed6", deserialize_with = "number")]
    pub r2_deg: f64,
    /// Right eye's link 3 angle (deg).
    #[serde(serialize_with = "fixed6", deserialize_with = "number")]
    pub r3_deg: f64,
    /// Features matched between the rectified images.
    pub matches: u64,
    /// |vertical disparity| median (px); empty without matches.
    #[serde(serialize_with = "finite6", deserialize_with = "number")]
    pub vertical_p50_px: f64,
    /// |vertical disparity| 95th percentile (px); empty without matches.
    #[serde(serialize_with = "finite6", deserialize_with = "number")]
    pub vertical_p95_px: f64,
    /// Rotation error about x (deg, left home frame); empty without a fit.
    #[serde(serialize_with = "finite6", deserialize_with = "number")]
    pub rot_x_deg: f64,
    /// Rotation error about y (deg); empty without a fit.
    #[serde(serialize_with = "finite6", deserialize_with = "number")]
    pub rot_y_deg: f64,
    /// Rotation error about z (deg); empty without a fit.
    #[serde(serialize_with = "finite6", deserialize_with = "number")]
    pub rot_z_deg: f64,
    /// 1-sigma of `rot_x_deg`; empty without a fit.
    #[serde(serialize_with = "finite6", deserialize_with = "number")]
    pub rot_sigma_x_deg: f64,
    /// 1-sigma of `rot_y_deg`; empty without a fit.
    #[serde(serialize_with = "finite6", deserialize_with = "number")]
    pub rot_sigma_y_deg: f64,
    /// 1-sigma of `rot_z_deg`; empty without a fit.
    #[serde(serialize_with = "finite6", deserialize_with = "number")]
    pub rot_sigma_z_deg: f64,
    /// The left camera's angular speed (deg/s); NaN in logs before the timing evidence.
    #[serde(serialize_with = "fixed3", deserialize_with = "number", default = "nan")]
    pub speed_l_deg_s: f64,
    /// The right camera's angular speed (deg/s).
    #[serde(serialize_with = "fixed3", deserialize_with = "number", default = "nan")]
    pub speed_r_deg_s: f64,
    /// How much the left camera's mean angular velocity changed from the 15 ms before the instant to the 15 ms
    /// after (deg/s; large: the eye accelerated while the rows exposed).
    #[serde(serialize_with = "fixed3", deserialize_with = "number", default = "nan")]
    pub accel_l_deg_s: f64,
    /// The same for the right camera (deg/s).
    #[serde(serialize_with = "fixed3", deserialize_with = "number", default = "nan")]
    pub accel_r_deg_s: f64,
    /// The rolling-shutter readout the run applied (ms).
    #[serde(serialize_with = "fixed4", deserialize_with = "number", default = "nan")]
    pub readout_ms: f64,
    /// The exposure the run assumed (ms).
    #[serde(serialize_with = "fixed4", deserialize_with = "number", default = "nan")]
    pub exposure_ms: f64,
    /// The row fraction the frames' stamps fix (`SourcePair::readout_anchor`).
    #[serde(serialize_with = "shortest", deserialize_with = "number", default = "nan")]
    pub readout_anchor: f64,
    /// The left eye's encoder time offset the run applied (ms); empty without a timing context.
    #[serde(serialize_with = "finite6", deserialize_with = "number", default = "nan")]
    pub offset_l_ms: f64,
    /// The right eye's (ms); empty without a timing context.
    #[serde(serialize_with = "finite6", deserialize_with = "number", default = "nan")]
    pub offset_r_ms: f64,
    /// Row bands the rolling-shutter correction used on the frame (0: corrected as a whole, at its instant);
    /// `None` in older logs.
    #[serde(default)]
    pub row_bands: Option<u64>,
    /// The run's identity (`SelfCheckConfig::run_id`); `None` in older logs.
    #[serde(default)]
    pub run_id: Option<u64>,
}

impl FrameRecord {
    /// A column logs have had since the timing evidence: a log without it has no timing columns.
    pub const TIMING_COLUMN: &'static str = "speed_l_deg_s";

    /// Both eyes' link angles (deg), [left, right].
    pub fn theta(&self) -> [[f64; 3]; 2] {
        [[self.l1_deg, self.l2_deg, self.l3_deg], [self.r1_deg, self.r2_deg, self.r3_deg]]
    }

    /// The rotation error (deg; NaN without a fit).
    pub fn rotation_deg(&self) -> [f64; 3] {
        [self.rot_x_deg, self.rot_y_deg, self.rot_z_deg]
    }
}

/// One line of the match log (`<log>.matches.csv`, [`match_log_path`]): a match of a checked frame and its
/// timing evidence.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct MatchRecord {
    /// The frame's pipeline sequence number.
    pub seq: u64,
    /// Left rectified x (px).
    #[serde(serialize_with = "fixed3", deserialize_with = "finite")]
    pub xl: f64,
    /// Left rectified y (px).
    #[serde(serialize_with = "fixed3", deserialize_with = "finite")]
    pub yl: f64,
    /// Right rectified x (px).
    #[serde(serialize_with = "fixed3", deserialize_with = "finite")]
    pub xr: f64,
    /// Right rectified y (px).
    #[serde(serialize_with = "fixed3", deserialize_with = "finite")]
    pub yr: f64,
    /// Raw row of the left point, as a fraction of the image (0 = top, 1 = bottom).
    #[serde(serialize_with = "fixed5", deserialize_with = "finite")]
    pub row_l: f64,
    /// Raw row of the right point (fraction).
    #[serde(serialize_with = "fixed5", deserialize_with = "finite")]
    pub row_r: f64,
    /// Vertical disparity `yr - yl` (px).
    #[serde(serialize_with = "fixed4", deserialize_with = "finite")]
    pub dy_px: f64,
    /// The match's design row for the rotation error, x (px/rad).
    #[serde(serialize_with = "fixed3", deserialize_with = "finite")]
    pub j_x: f64,
    /// The same, y (px/rad).
    #[serde(serialize_with = "fixed3", deserialize_with = "finite")]
    pub j_y: f64,
    /// The same, z (px/rad).
    #[serde(serialize_with = "fixed3", deserialize_with = "finite")]
    pub j_z: f64,
    /// Change of the vertical disparity per millisecond of the left eye's time error (px/ms).
    #[serde(serialize_with = "fixed6", deserialize_with = "finite")]
    pub s_l_px_per_ms: f64,
    /// The same for the right eye (px/ms).
    #[serde(serialize_with = "fixed6", deserialize_with = "finite")]
    pub s_r_px_per_ms: f64,
    /// Parallax of the left camera's centre moving for a millisecond (px/ms).
    #[serde(serialize_with = "fixed6", deserialize_with = "finite")]
    pub u_l_px_per_ms: f64,
    /// The same for the right camera (px/ms).
    #[serde(serialize_with = "fixed6", deserialize_with = "finite")]
    pub u_r_px_per_ms: f64,
    /// The run's identity; `None` in older logs.
    #[serde(default)]
    pub run_id: Option<u64>,
}

/// The match log of a per-frame log `log`: `x.csv` -> `x.matches.csv`.
pub fn match_log_path(log: &Path) -> PathBuf {
    log.with_extension("matches.csv")
}

/// The run's configuration beside a log (`x.csv` -> `x.run.toml`): what `abvs calib self-check` re-runs a
/// replay with, the timing replaced by its estimate.
pub fn run_config_path(log: &Path) -> PathBuf {
    log.with_extension("run.toml")
}

/// The line of `<log>.run.toml` that names its run (a TOML comment: the file stays a configuration).
pub fn run_id_line(run_id: u64) -> String {
    format!("{RUN_ID_PREFIX}{run_id}")
}

const RUN_ID_PREFIX: &str = "# self-check run_id = ";
const CONFIG_DIGEST_PREFIX: &str = "# self-check config_sha256 = ";
const SESSION_DIGEST_PREFIX: &str = "# self-check session_sha256 = ";
/// Every header line of a `<log>.run.toml` starts so.
const HEADER_PREFIX: &str = "# self-check ";

/// The SHA-256 of `bytes`, in hex.
pub fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::Digest;
    sha2::Sha256::digest(bytes).iter().map(|b| format!("{b:02x}")).collect()
}

/// The text of `<log>.run.toml`: TOML comments naming the run ([`run_id_line`]), the SHA-256 of the
/// configuration below them (an edit after the run shows) and, for a replay, of the session's session.toml
/// as the run read it (another session, or one rendered again at the same place, shows); then the
/// configuration.
pub fn run_config_text(run_id: u64, config_toml: &str, session_toml: Option<&[u8]>) -> String {
    let mut s = format!("{}\n{CONFIG_DIGEST_PREFIX}{}\n", run_id_line(run_id), sha256_hex(config_toml.as_bytes()));
    if let Some(b) = session_toml {
        s += &format!("{SESSION_DIGEST_PREFIX}{}\n", sha256_hex(b));
    }
    s + config_toml
}

/// What a `<log>.run.toml`'s header says of its run (each `None` in older files).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RunHeader {
    /// The run ([`run_id_line`]).
    pub run_id: Option<u64>,
    /// The SHA-256 (hex) of the configuration as the run wrote it.
    pub config_sha256: Option<String>,
    /// The SHA-256 (hex) of the replayed session's session.toml as the run read it (`None` live).
    pub session_sha256: Option<String>,
    /// Whether the configuration below the header still has the digest the run wrote (true without one).
    pub config_intact: bool,
}

/// Reads a `<log>.run.toml`'s header (`Err` with the value when its run_id is not a number).
pub fn run_header(text: &str) -> Result<RunHeader, String> {
    let mut h = RunHeader { run_id: run_id_of_config(text)?, ..Default::default() };
    let mut body = text;
    while body.starts_with(HEADER_PREFIX) {
        let (line, rest) = body.split_once('\n').unwrap_or((body, ""));
        if let Some(d) = line.strip_prefix(CONFIG_DIGEST_PREFIX) {
            h.config_sha256 = Some(d.trim().to_string());
        } else if let Some(d) = line.strip_prefix(SESSION_DIGEST_PREFIX) {
            h.session_sha256 = Some(d.trim().to_string());
        }
        body = rest;
    }
    h.config_intact = h.config_sha256.as_deref().is_none_or(|d| d == sha256_hex(body.as_bytes()));
    Ok(h)
}

/// The run a `<log>.run.toml`'s text names (its [`run_id_line`]; `Ok(None)` in older files, `Err` with the
/// value when it is not a number).
pub fn run_id_of_config(text: &str) -> Result<Option<u64>, String> {
    let Some(rest) = text.lines().find_map(|l| l.strip_prefix(RUN_ID_PREFIX)) else { return Ok(None) };
    rest.trim().parse().map(Some).map_err(|_| rest.to_string())
}

/// A record kind of the logs: its header line, its CSV line.
pub trait LogRecord: Serialize + serde::de::DeserializeOwned + Default {
    /// The header line (the fields' names, comma separated).
    fn header() -> String {
        let mut w = csv::WriterBuilder::new().has_headers(true).from_writer(Vec::new());
        w.serialize(Self::default()).expect("a record serialises");
        let bytes = w.into_inner().expect("written to memory");
        let text = String::from_utf8(bytes).expect("field names are UTF-8");
        text.lines().next().expect("a header line").to_string()
    }
}

impl LogRecord for FrameRecord {}
impl LogRecord for MatchRecord {}

/// Writes records of one kind, one line each (the header is written when the writer is made).
pub struct LogWriter<W: std::io::Write> {
    csv: csv::Writer<W>,
}

impl<W: std::io::Write> LogWriter<W> {
    /// A writer whose first line is `R`'s header.
    pub fn new<R: LogRecord>(mut out: W) -> std::io::Result<Self> {
        writeln!(out, "{}", R::header())?;
        Ok(LogWriter { csv: csv::WriterBuilder::new().has_headers(false).from_writer(out) })
    }

    /// Writes one record as a line.
    pub fn write<R: LogRecord>(&mut self, r: &R) -> std::io::Result<()> {
        self.csv.serialize(r).map_err(std::io::Error::other)
    }

    /// Flushes the lines written so far.
    pub fn flush(&mut self) -> std::io::Result<()> {
        self.csv.flush()
    }
}

/// Why a log cannot be read.
#[derive(Debug, thiserror::Error)]
pub enum LogError {
    /// The file cannot be opened or read.
    #[error("reading {}", path.display())]
    Io {
        /// The log.
        path: PathBuf,
        /// What the system said.
        #[source]
        source: csv::Error,
    },
    /// A line that is not a CSV record.
    #[error("{}:{line}: unreadable record", path.display())]
    Record {
        /// The log.
        path: PathBuf,
        /// Its line (1 = the header).
        line: u64,
        /// What the CSV reader said.
        #[source]
        source: csv::Error,
    },
    /// A column the record kind needs is not in the header.
    #[error("{}: no column `{column}`", path.display())]
    MissingColumn {
        /// The log.
        path: PathBuf,
        /// The column.
        column: String,
    },
    /// A field whose value does not read as its column's type.
    #[error("{}:{line}: `{column}`: {message}", path.display())]
    Field {
        /// The log.
        path: PathBuf,
        /// Its line.
        line: u64,
        /// The column.
        column: String,
        /// What is wrong with the value (it names the value).
        message: String,
    },
}

/// One record of a log and its line (1 = the header).
#[derive(Debug, Clone, PartialEq)]
pub struct Line<R> {
    /// The line in the file.
    pub line: u64,
    /// The record.
    pub record: R,
}

/// A log read whole: its columns and its records.
#[derive(Debug, Clone)]
pub struct Log<R> {
    /// The header's column names, in file order.
    pub columns: Vec<String>,
    /// The records, in file order.
    pub lines: Vec<Line<R>>,
}

impl<R> Log<R> {
    /// Whether the header has `column`.
    pub fn has_column(&self, column: &str) -> bool {
        self.columns.iter().any(|c| c == column)
    }

    /// The records without their lines.
    pub fn records(&self) -> impl Iterator<Item = &R> {
        self.lines.iter().map(|l| &l.record)
    }
}

/// Reads a log of records `R` (an error names the file, the line and the column).
pub fn read_log<R: LogRecord>(path: &Path) -> Result<Log<R>, LogError> {
    let io = |source| LogError::Io { path: path.to_path_buf(), source };
    let mut rd = csv::Reader::from_path(path).map_err(io)?;
    let head = rd.headers().map_err(io)?.clone();
    let columns: Vec<String> = head.iter().map(str::to_string).collect();
    let mut lines = Vec::new();
    let mut rec = csv::StringRecord::new();
    loop {
        let line = rd.position().line();
        match rd.read_record(&mut rec) {
            Ok(false) => break,
            Ok(true) => {}
            Err(source) => return Err(LogError::Record { path: path.to_path_buf(), line, source }),
        }
        let line = rec.position().map_or(line, |p| p.line());
        let record = rec.deserialize::<R>(Some(&head)).map_err(|e| field_error(path, line, &head, &rec, e))?;
        lines.push(Line { line, record });
    }
    Ok(Log { columns, lines })
}

fn field_error(path: &Path, line: u64, head: &csv::StringRecord, rec: &csv::StringRecord, e: csv::Error) -> LogError {
    let path = path.to_path_buf();
    let csv::ErrorKind::Deserialize { err, .. } = e.kind() else {
        return LogError::Record { path, line, source: e };
    };
    let message = err.kind().to_string();
    if let Some(column) = message.strip_prefix("missing field `").and_then(|m| m.strip_suffix('`')) {
        return LogError::MissingColumn { path, column: column.to_string() };
    }
    // csv knows the field of its own parse errors; a field's reader (`number`, `finite`) names the value it
    // refused, and the columns are read in order, so the first holding that value is the one
    let field = err.field().map(|k| k as usize).or_else(|| {
        let value = message.split('`').nth(1)?;
        rec.iter().position(|v| v.trim() == value.trim())
    });
    match field.and_then(|k| Some((head.get(k)?, rec.get(k)?))) {
        Some((column, value)) => {
            // the float fields name their value themselves; the others get it here
            let message = if message.contains('`') { message } else { format!("`{value}`: {message}") };
            LogError::Field { path, line, column: column.to_string(), message }
        }
        None => LogError::Record { path, line, source: e },
    }
}

fn nan() -> f64 {
    f64::NAN
}

/// Reads a number; an empty field is NaN.
fn number<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    let s = <std::borrow::Cow<'de, str>>::deserialize(d)?;
    let s = s.trim();
    if s.is_empty() {
        return Ok(f64::NAN);
    }
    s.parse().map_err(|_| serde::de::Error::custom(format!("`{s}` is not a number")))
}

/// Reads a finite number (the match log has no empty fields).
fn finite<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    let s = <std::borrow::Cow<'de, str>>::deserialize(d)?;
    match s.trim().parse::<f64>() {
        Ok(x) if x.is_finite() => Ok(x),
        _ => Err(serde::de::Error::custom(format!("`{s}` is not a finite number"))),
    }
}

fn fixed<S: Serializer>(x: f64, decimals: usize, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(&format!("{x:.decimals$}"))
}

fn fixed3<S: Serializer>(x: &f64, s: S) -> Result<S::Ok, S::Error> {
    fixed(*x, 3, s)
}

fn fixed4<S: Serializer>(x: &f64, s: S) -> Result<S::Ok, S::Error> {
    fixed(*x, 4, s)
}

fn fixed5<S: Serializer>(x: &f64, s: S) -> Result<S::Ok, S::Error> {
    fixed(*x, 5, s)
}

fn fixed6<S: Serializer>(x: &f64, s: S) -> Result<S::Ok, S::Error> {
    fixed(*x, 6, s)
}

/// Six decimals; empty when not finite.
fn finite6<S: Serializer>(x: &f64, s: S) -> Result<S::Ok, S::Error> {
    if x.is_finite() {
        fixed(*x, 6, s)
    } else {
        s.serialize_str("")
    }
}

/// The shortest decimal that reads back as the value (Rust's `Display`).
fn shortest<S: Serializer>(x: &f64, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(&x.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn headers_are_the_fields_and_records_round_trip() {
        assert!(FrameRecord::header().starts_with("seq,t_ns,l1_deg,") && FrameRecord::header().ends_with(",run_id"));
        assert!(FrameRecord::header().split(',').any(|c| c == FrameRecord::TIMING_COLUMN));
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.matches.csv");
        let m =
            MatchRecord { seq: 3, xl: 1.5, dy_px: -0.25, s_l_px_per_ms: 0.125, run_id: Some(9), ..Default::default() };
        let mut w = LogWriter::new::<MatchRecord>(std::fs::File::create(&p).unwrap()).unwrap();
        w.write(&m).unwrap();
        w.flush().unwrap();
        drop(w);
        let text = std::fs::read_to_string(&p).unwrap();
        assert_eq!(
            text.lines().nth(1).unwrap(),
            "3,1.500,0.000,0.000,0.000,0.00000,0.00000,-0.2500,0.000,0.000,0.000,0.125000,0.000000,0.000000,0.000000,9"
        );
        let log = read_log::<MatchRecord>(&p).unwrap();
        assert_eq!((log.lines[0].line, log.lines[0].record), (2, m));
    }

    #[test]
    fn a_damaged_log_names_file_line_and_column() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.matches.csv");
        let head = MatchRecord::header();
        std::fs::write(
            &p,
            format!(
                "{head}\n0,1,2,3,4,0.1,0.2,0.5,1,2,3,0.01,0.02,0,0,7\n0,1,2,3,4,0.1,0.2,oops,1,2,3,0.01,0.02,0,0,7\n"
            ),
        )
        .unwrap();
        let e = read_log::<MatchRecord>(&p).unwrap_err().to_string();
        assert!(e.contains("x.matches.csv:3") && e.contains("dy_px") && e.contains("oops"), "{e}");
        std::fs::write(&p, format!("{head}\n-1,1,2,3,4,0.1,0.2,0.5,1,2,3,0.01,0.02,0,0,7\n")).unwrap();
        let e = read_log::<MatchRecord>(&p).unwrap_err().to_string();
        assert!(e.contains("x.matches.csv:2") && e.contains("`seq`: `-1`"), "{e}");
        std::fs::write(&p, "seq,xl\n1,2\n").unwrap();
        let e = read_log::<MatchRecord>(&p).unwrap_err().to_string();
        assert!(e.contains("no column `yl`"), "{e}");
        // a column added later reads as absent in an older log
        std::fs::write(&p, head.replace(",run_id", "") + "\n0,1,2,3,4,0.1,0.2,0.5,1,2,3,0.01,0.02,0,0\n").unwrap();
        assert_eq!(read_log::<MatchRecord>(&p).unwrap().lines[0].record.run_id, None);
    }
}
