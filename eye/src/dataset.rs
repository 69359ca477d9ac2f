//! Calibration dataset files (`shared/spec/dataset.md`): one CSV per eye and session, one
//! header line, one row per sample in acquisition order.
//!
//! Reading finds columns by name (any order), trims blanks around every field, keeps unknown
//! extra columns as text, and refuses bad input with `file:line: column X: what is wrong`
//! ([`EyeError::File`], 1-based physical line, the header is line 1 of a file without leading
//! blank lines). Nothing is skipped silently: a value out of its physical range is an error,
//! not a dropped row; only blank lines, which hold no sample, are passed over. Writing applies the same checks, so every file this module
//! writes reads back, bit for bit (floats use Rust's shortest round-trip `Display`).
use crate::error::{EyeError, Result};
use std::collections::HashMap;
use std::io::{Read, Write};
use std::path::Path;

/// The columns every dataset file has (any order in a file; this order when written).
pub const REQUIRED_COLUMNS: [&str; 11] = [
    "seq",
    "t_s",
    "theta1_deg",
    "theta2_deg",
    "theta3_deg",
    "alpha_deg",
    "beta_deg",
    "gamma_deg",
    "x_mm",
    "y_mm",
    "z_mm",
];
/// Optional group: the commanded ideal pose (all three or none).
pub const CMD_COLUMNS: [&str; 3] = ["cmd_alpha_deg", "cmd_beta_deg", "cmd_gamma_deg"];
/// Optional group: gravity direction in the base frame B (all three or none).
pub const GRAVITY_COLUMNS: [&str; 3] = ["gx", "gy", "gz"];
/// Gravity when the file has no gx, gy, gz: +y of B, the head upright.
pub const DEFAULT_GRAVITY: [f64; 3] = [0.0, 1.0, 0.0];
/// Largest accepted | |g| - 1 |.
pub const GRAVITY_UNIT_TOLERANCE: f64 = 1e-3;

/// One measured sample (a row of the file).
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    pub seq: u64,
    pub t_s: f64,
    pub theta_deg: [f64; 3],
    /// measured pose P = [alpha, beta, gamma (deg), x, y, z (mm)]
    pub pose: [f64; 6],
    /// cmd_alpha_deg, cmd_beta_deg, cmd_gamma_deg
    pub cmd_deg: Option<[f64; 3]>,
    /// gx, gy, gz unit vector in base frame B
    pub gravity: Option<[f64; 3]>,
    /// values of unknown extra columns, in [`Dataset::extra_columns`] order
    pub extra: Vec<String>,
}

impl Sample {
    /// Gravity in B; +y (the head upright) when the file has none.
    pub fn gravity_or_default(&self) -> [f64; 3] {
        self.gravity.unwrap_or(DEFAULT_GRAVITY)
    }
}

/// A whole dataset file: samples in acquisition order and the names of its extra columns.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Dataset {
    pub samples: Vec<Sample>,
    pub extra_columns: Vec<String>,
}

/// Physical range (inclusive) of a numeric column, or `None` when it has none of its own
/// (t_s and the gravity components are checked separately).
fn physical_range(col: &str) -> Option<(f64, f64, &'static str)> {
    match col {
        "theta1_deg" | "theta2_deg" | "theta3_deg" => Some((-360.0, 360.0, "deg")),
        "alpha_deg" | "gamma_deg" | "cmd_alpha_deg" | "cmd_gamma_deg" => Some((-90.0, 90.0, "deg")),
        "beta_deg" | "cmd_beta_deg" => Some((-180.0, 180.0, "deg")),
        "x_mm" | "y_mm" | "z_mm" => Some((-1000.0, 1000.0, "mm")),
        _ => None,
    }
}

/// Checks one already-parsed value of a known float column; the message names the column.
fn check_value(col: &str, v: f64) -> std::result::Result<(), String> {
    if !v.is_finite() {
        return Err(format!("column {col}: {v} is not a finite number"));
    }
    if col == "t_s" && v < 0.0 {
        return Err(format!("column t_s: {v} is negative (time since the session start)"));
    }
    if let Some((lo, hi, unit)) = physical_range(col) {
        if !(lo..=hi).contains(&v) {
            return Err(format!("column {col}: {v} is outside the physical range [{lo}, {hi}] {unit}"));
        }
    }
    Ok(())
}

fn check_gravity(g: &[f64; 3]) -> std::result::Result<(), String> {
    for (col, v) in GRAVITY_COLUMNS.iter().zip(g) {
        check_value(col, *v)?;
    }
    let n = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
    if (n - 1.0).abs() > GRAVITY_UNIT_TOLERANCE {
        return Err(format!(
            "columns gx, gy, gz: gravity ({}, {}, {}) has norm {n}, not a unit vector \
             (tolerance {GRAVITY_UNIT_TOLERANCE})",
            g[0], g[1], g[2]
        ));
    }
    Ok(())
}

/// All value checks of one sample except seq ordering (shared by reader and writer).
fn check_sample(s: &Sample) -> std::result::Result<(), String> {
    check_value("t_s", s.t_s)?;
    for (col, v) in REQUIRED_COLUMNS[2..5].iter().zip(&s.theta_deg) {
        check_value(col, *v)?;
    }
    for (col, v) in REQUIRED_COLUMNS[5..].iter().zip(&s.pose) {
        check_value(col, *v)?;
    }
    if let Some(c) = &s.cmd_deg {
        for (col, v) in CMD_COLUMNS.iter().zip(c) {
            check_value(col, *v)?;
        }
    }
    if let Some(g) = &s.gravity {
        check_gravity(g)?;
    }
    Ok(())
}

/// Where each known column sits in a file's rows.
struct Layout {
    required: [usize; 11],
    cmd: Option<[usize; 3]>,
    gravity: Option<[usize; 3]>,
    /// (index in the row, name) of the unknown columns, in file order
    extra: Vec<(usize, String)>,
    n_fields: usize,
}

/// Finds an optional all-or-nothing column group; a partial group names the missing column.
fn find_group(index: &HashMap<&str, usize>, cols: &[&str; 3]) -> std::result::Result<Option<[usize; 3]>, String> {
    let found = cols.map(|c| index.get(c).copied());
    if found.iter().all(Option::is_none) {
        return Ok(None);
    }
    if let Some(k) = found.iter().position(Option::is_none) {
        return Err(format!(
            "incomplete column group {}: column {} is missing (the group is all or nothing)",
            cols.join(", "),
            cols[k]
        ));
    }
    Ok(Some(found.map(|x| x.unwrap_or_default())))
}

impl Layout {
    fn from_header(fields: &[String]) -> std::result::Result<Layout, String> {
        if fields.len() == 1 && fields[0].is_empty() {
            return Err(format!("empty header line: expected the column names {}", REQUIRED_COLUMNS.join(", ")));
        }
        let mut index: HashMap<&str, usize> = HashMap::new();
        for (k, name) in fields.iter().enumerate() {
            if name.is_empty() {
                return Err(format!("header: column {} has an empty name", k + 1));
            }
            if let Some(prev) = index.insert(name.as_str(), k) {
                return Err(format!("duplicate column name {name:?} (columns {} and {})", prev + 1, k + 1));
            }
        }
        let missing: Vec<&str> = REQUIRED_COLUMNS.iter().copied().filter(|c| !index.contains_key(c)).collect();
        if !missing.is_empty() {
            // A first line of numbers means the header itself is absent.
            if fields.iter().all(|f| f.parse::<f64>().is_ok()) {
                return Err(format!(
                    "missing header line: the first line holds numbers, expected the column \
                     names {}",
                    REQUIRED_COLUMNS.join(", ")
                ));
            }
            let list: Vec<String> = missing.iter().map(|c| format!("column {c}")).collect();
            return Err(format!("missing required {}", list.join(", ")));
        }
        let required = REQUIRED_COLUMNS.map(|c| index[c]);
        let cmd = find_group(&index, &CMD_COLUMNS)?;
        let gravity = find_group(&index, &GRAVITY_COLUMNS)?;
        let extra = fields
            .iter()
            .enumerate()
            .filter(|(_, n)| {
                !REQUIRED_COLUMNS.contains(&n.as_str())
                    && !CMD_COLUMNS.contains(&n.as_str())
                    && !GRAVITY_COLUMNS.contains(&n.as_str())
            })
            .map(|(k, n)| (k, n.clone()))
            .collect();
        Ok(Layout { required, cmd, gravity, extra, n_fields: fields.len() })
    }
}

fn parse_f64(rec: &csv::StringRecord, k: usize, col: &str) -> std::result::Result<f64, String> {
    let s = &rec[k];
    let v: f64 = s.parse().map_err(|_| format!("column {col}: {s:?} is not a number"))?;
    if !v.is_finite() {
        return Err(format!("column {col}: {s:?} is not a finite number"));
    }
    check_value(col, v)?;
    Ok(v)
}

fn parse_seq(rec: &csv::StringRecord, k: usize) -> std::result::Result<u64, String> {
    let s = &rec[k];
    s.parse::<u64>().map_err(|_| {
        if s.parse::<f64>().is_ok() {
            format!("column seq: {s:?} is not a non-negative integer")
        } else {
            format!("column seq: {s:?} is not a number")
        }
    })
}

fn parse_row(rec: &csv::StringRecord, lay: &Layout) -> std::result::Result<Sample, String> {
    if rec.len() != lay.n_fields {
        return Err(format!("wrong number of fields: {} found, the header has {}", rec.len(), lay.n_fields));
    }
    let r = &lay.required;
    let f = |j: usize| parse_f64(rec, r[j], REQUIRED_COLUMNS[j]);
    let seq = parse_seq(rec, r[0])?;
    let t_s = f(1)?;
    let theta_deg = [f(2)?, f(3)?, f(4)?];
    let pose = [f(5)?, f(6)?, f(7)?, f(8)?, f(9)?, f(10)?];
    let group = |idx: &Option<[usize; 3]>, cols: &[&str; 3]| -> std::result::Result<_, String> {
        match idx {
            None => Ok(None),
            Some(k) => Ok(Some([
                parse_f64(rec, k[0], cols[0])?,
                parse_f64(rec, k[1], cols[1])?,
                parse_f64(rec, k[2], cols[2])?,
            ])),
        }
    };
    let cmd_deg = group(&lay.cmd, &CMD_COLUMNS)?;
    let gravity = group(&lay.gravity, &GRAVITY_COLUMNS)?;
    if let Some(g) = &gravity {
        check_gravity(g)?;
    }
    let extra = lay.extra.iter().map(|(k, _)| rec[*k].to_string()).collect();
    Ok(Sample { seq, t_s, theta_deg, pose, cmd_deg, gravity, extra })
}

/// Physical line numbers of records. csv's own record positions point just past the
/// previous record, i.e. at any blank lines before this one (and at the LF of a CRLF), so we
/// skip line breaks from there and count LFs ourselves, incrementally.
struct Lines<'a> {
    buf: &'a [u8],
    pos: usize,
    line: usize,
}

impl Lines<'_> {
    fn at(&mut self, pos: Option<&csv::Position>) -> usize {
        let Some(p) = pos else { return self.line };
        let mut b = (p.byte() as usize).min(self.buf.len());
        while b < self.buf.len() && matches!(self.buf[b], b'\n' | b'\r') {
            b += 1;
        }
        if b < self.pos {
            (self.pos, self.line) = (0, 1);
        }
        self.line += self.buf[self.pos..b].iter().filter(|&&c| c == b'\n').count();
        self.pos = b;
        self.line
    }
}

/// A csv-level failure (bad UTF-8, unterminated quote) at the line it names.
fn csv_error(name: &Path, e: &csv::Error, lines: &mut Lines) -> EyeError {
    let line = lines.at(e.position());
    let msg = match e.kind() {
        csv::ErrorKind::Utf8 { err, .. } => {
            format!("invalid UTF-8 in field {}", err.field() + 1)
        }
        _ => e.to_string(),
    };
    EyeError::file(name, Some(line), msg)
}

impl Dataset {
    /// Reads and checks a dataset file.
    pub fn read(path: &Path) -> Result<Dataset> {
        let f = std::fs::File::open(path).map_err(|e| EyeError::io(path, e))?;
        Dataset::from_reader(std::io::BufReader::new(f), path)
    }

    /// Reads and checks a dataset from any reader; `name` is the file name used in errors.
    pub fn from_reader<R: Read>(mut r: R, name: &Path) -> Result<Dataset> {
        // Whole input in memory (a dataset is a few MB at most), for exact line numbers.
        let mut buf = Vec::new();
        r.read_to_end(&mut buf).map_err(|e| EyeError::io(name, e))?;
        let mut lines = Lines { buf: &buf, pos: 0, line: 1 };
        let mut rdr = csv::ReaderBuilder::new()
            .has_headers(false)
            // Field-count errors get our own message, with the line.
            .flexible(true)
            .trim(csv::Trim::All)
            .from_reader(buf.as_slice());
        let mut rec = csv::StringRecord::new();
        let has_header = rdr.read_record(&mut rec).map_err(|e| csv_error(name, &e, &mut lines))?;
        if !has_header {
            return Err(EyeError::file(
                name,
                Some(1),
                format!(
                    "empty file: missing the header line (expected the column names {})",
                    REQUIRED_COLUMNS.join(", ")
                ),
            ));
        }
        let header_line = lines.at(rec.position());
        let mut names: Vec<String> = rec.iter().map(str::to_string).collect();
        // An editor's byte-order mark is not part of the first name.
        if let Some(first) = names.first_mut() {
            *first = first.trim_start_matches('\u{feff}').trim().to_string();
        }
        let lay = Layout::from_header(&names).map_err(|m| EyeError::file(name, Some(header_line), m))?;

        let mut ds = Dataset { samples: Vec::new(), extra_columns: lay.extra.iter().map(|(_, n)| n.clone()).collect() };
        let mut prev: Option<(u64, usize)> = None;
        loop {
            match rdr.read_record(&mut rec) {
                Ok(true) => {}
                Ok(false) => break,
                Err(e) => return Err(csv_error(name, &e, &mut lines)),
            }
            let line = lines.at(rec.position());
            // A line of blanks holds no sample (csv already skips truly empty lines).
            if rec.len() == 1 && rec[0].is_empty() {
                continue;
            }
            let s = parse_row(&rec, &lay).map_err(|m| EyeError::file(name, Some(line), m))?;
            if let Some((pseq, pline)) = prev {
                if s.seq <= pseq {
                    return Err(EyeError::file(
                        name,
                        Some(line),
                        format!(
                            "column seq: {} is not greater than the previous seq {pseq} \
                             (line {pline}); rows must be in acquisition order",
                            s.seq
                        ),
                    ));
                }
            }
            prev = Some((s.seq, line));
            ds.samples.push(s);
        }
        Ok(ds)
    }

    /// Writes the dataset to a file (see [`Dataset::to_writer`]).
    pub fn write(&self, path: &Path) -> Result<()> {
        let f = std::fs::File::create(path).map_err(|e| EyeError::io(path, e))?;
        self.write_named(std::io::BufWriter::new(f), path)
    }

    /// Writes the dataset as CSV: the required columns in [`REQUIRED_COLUMNS`] order, then
    /// cmd_* and gx, gy, gz when the samples have them, then the extra columns. The samples
    /// are checked as on reading first, so a file that was written always reads back.
    pub fn to_writer<W: Write>(&self, w: W) -> Result<()> {
        self.write_named(w, Path::new("<dataset writer>"))
    }

    fn write_named<W: Write>(&self, w: W, name: &Path) -> Result<()> {
        let (has_cmd, has_gravity) = self.check_for_write(name)?;
        let mut wr = csv::WriterBuilder::new().from_writer(w);
        let io = |e: csv::Error| EyeError::io(name, e.into());
        let mut header: Vec<&str> = REQUIRED_COLUMNS.to_vec();
        if has_cmd {
            header.extend(CMD_COLUMNS);
        }
        if has_gravity {
            header.extend(GRAVITY_COLUMNS);
        }
        header.extend(self.extra_columns.iter().map(String::as_str));
        wr.write_record(&header).map_err(io)?;
        let mut row: Vec<String> = Vec::with_capacity(header.len());
        for s in &self.samples {
            row.clear();
            row.push(s.seq.to_string());
            row.push(s.t_s.to_string());
            row.extend(s.theta_deg.iter().chain(&s.pose).map(f64::to_string));
            if let Some(c) = &s.cmd_deg {
                row.extend(c.iter().map(f64::to_string));
            }
            if let Some(g) = &s.gravity {
                row.extend(g.iter().map(f64::to_string));
            }
            row.extend(s.extra.iter().cloned());
            wr.write_record(&row).map_err(io)?;
        }
        wr.flush().map_err(|e| EyeError::io(name, e))
    }

    /// Refuses what could not be read back; returns whether the cmd and gravity groups are
    /// written. Errors carry the line the sample would have had.
    fn check_for_write(&self, name: &Path) -> Result<(bool, bool)> {
        let header_err = |m: String| EyeError::file(name, Some(1), format!("cannot write: {m}"));
        let mut seen: Vec<&str> = Vec::new();
        for c in &self.extra_columns {
            let known = REQUIRED_COLUMNS.contains(&c.as_str())
                || CMD_COLUMNS.contains(&c.as_str())
                || GRAVITY_COLUMNS.contains(&c.as_str());
            if known || seen.contains(&c.as_str()) {
                return Err(header_err(format!("duplicate column name {c:?}")));
            }
            if c.trim().is_empty() || c.trim() != c {
                return Err(header_err(format!("extra column name {c:?} is empty or has surrounding blanks")));
            }
            seen.push(c);
        }
        let has_cmd = self.samples.first().is_some_and(|s| s.cmd_deg.is_some());
        let has_gravity = self.samples.first().is_some_and(|s| s.gravity.is_some());
        let mut prev: Option<u64> = None;
        for (k, s) in self.samples.iter().enumerate() {
            let line = k + 2;
            let err = |m: String| EyeError::file(name, Some(line), format!("cannot write sample seq {}: {m}", s.seq));
            if s.cmd_deg.is_some() != has_cmd {
                return Err(err(format!("cmd_* present in some samples only (first sample: {has_cmd})")));
            }
            if s.gravity.is_some() != has_gravity {
                return Err(err(format!("gx, gy, gz present in some samples only (first sample: {has_gravity})")));
            }
            if s.extra.len() != self.extra_columns.len() {
                return Err(err(format!(
                    "{} extra values for {} extra columns",
                    s.extra.len(),
                    self.extra_columns.len()
                )));
            }
            if let Some(v) = s.extra.iter().find(|v| v.trim() != v.as_str()) {
                // Reading trims fields, so such a value would not come back as written.
                return Err(err(format!("extra value {v:?} has surrounding blanks")));
            }
            if let Some(p) = prev {
                if s.seq <= p {
                    return Err(err(format!("column seq: {} is not greater than the previous seq {p}", s.seq)));
                }
            }
            prev = Some(s.seq);
            check_sample(s).map_err(err)?;
        }
        Ok((has_cmd, has_gravity))
    }

    pub fn len(&self) -> usize {
        self.samples.len()
    }

    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// Whether the samples carry the commanded pose (cmd_* columns).
    pub fn has_cmd(&self) -> bool {
        self.samples.first().is_some_and(|s| s.cmd_deg.is_some())
    }

    /// Stable content hash for model manifests: FNV-1a 64 over the exact bits of every value
    /// (and the extra column names and values), as 16 lowercase hex digits. Equal after a
    /// write/read round trip; changes with any value, the sample order or the optional groups.
    pub fn content_hash(&self) -> String {
        let mut h = Fnv1a::new();
        h.bytes(b"abvs-dataset-v1");
        h.u64(self.extra_columns.len() as u64);
        for c in &self.extra_columns {
            h.str(c);
        }
        h.u64(self.samples.len() as u64);
        for s in &self.samples {
            h.u64(s.seq);
            h.f64(s.t_s);
            s.theta_deg.iter().chain(&s.pose).for_each(|v| h.f64(*v));
            for group in [&s.cmd_deg, &s.gravity] {
                match group {
                    None => h.bytes(&[0]),
                    Some(v) => {
                        h.bytes(&[1]);
                        v.iter().for_each(|x| h.f64(*x));
                    }
                }
            }
            for e in &s.extra {
                h.str(e);
            }
        }
        format!("{:016x}", h.0)
    }
}

/// FNV-1a 64: tiny, stable across platforms and Rust versions (unlike `DefaultHasher`).
struct Fnv1a(u64);

impl Fnv1a {
    fn new() -> Self {
        Fnv1a(0xcbf2_9ce4_8422_2325)
    }
    fn bytes(&mut self, b: &[u8]) {
        for &x in b {
            self.0 ^= u64::from(x);
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    fn u64(&mut self, v: u64) {
        self.bytes(&v.to_le_bytes());
    }
    fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }
    /// Length-prefixed, so ("ab","c") and ("a","bc") differ.
    fn str(&mut self, s: &str) {
        self.u64(s.len() as u64);
        self.bytes(s.as_bytes());
    }
}
