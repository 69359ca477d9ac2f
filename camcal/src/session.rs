//! Calibration sessions on disk (the format is described in camcal/README.md) and their
//! measurement into dataset files (dataset.md).
//!
//! ```text
//! DIR/session.toml   format = "abvs-session/1", camera = "camera.yaml" (OpenCV YAML intrinsics,
//!                    relative to DIR), target = "aprilgrid:6x6:88:0.3", home_counts = [c1, c2, c3]
//! DIR/index.csv      seq,t_s,image,count1,count2,count3 [,cmd_alpha_deg,cmd_beta_deg,cmd_gamma_deg] [,gx,gy,gz]
//! DIR/images/...     the images named by the index (paths relative to DIR)
//! DIR/truth.csv      (simulated sessions only) the true poses, a dataset file
//! ```
//! Home images are the rows whose counts equal `home_counts`.
use crate::detect::{detect_files, AprilDetector};
use crate::error::{CamcalError, Result};
use crate::measure::{solve, Failure, SolveOptions, Solved};
use crate::target::Target;
use abvs_camera::Camera;
use abvs_eye::dataset::{Dataset, Sample};
use abvs_eye::encoder::COUNTS_PER_REV;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

pub const FORMAT: &str = "abvs-session/1";

/// session.toml
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SessionMeta {
    pub format: String,
    /// Intrinsics file (OpenCV YAML), relative to the session directory.
    pub camera: String,
    /// Target spec, as `--target` takes it.
    pub target: String,
    /// Encoder counts of the three links at home.
    pub home_counts: [i64; 3],
}

/// One row of index.csv.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    pub seq: u64,
    pub t_s: f64,
    pub image: String,
    pub counts: [i64; 3],
    pub cmd_deg: Option<[f64; 3]>,
    pub gravity: Option<[f64; 3]>,
}

/// A session: its directory, metadata and index.
#[derive(Debug, Clone)]
pub struct Session {
    pub dir: PathBuf,
    pub meta: SessionMeta,
    pub rows: Vec<Row>,
}

fn file_err(path: &Path, msg: impl Into<String>) -> CamcalError {
    CamcalError::File { path: path.to_path_buf(), msg: msg.into() }
}

impl Session {
    pub fn read(dir: &Path) -> Result<Session> {
        let mp = dir.join("session.toml");
        let text = std::fs::read_to_string(&mp).map_err(|e| file_err(&mp, e.to_string()))?;
        let meta: SessionMeta = toml::from_str(&text).map_err(|e| file_err(&mp, e.to_string()))?;
        if meta.format != FORMAT {
            return Err(file_err(&mp, format!("format '{}', expected '{FORMAT}'", meta.format)));
        }
        let ip = dir.join("index.csv");
        let mut rd = csv::ReaderBuilder::new().from_path(&ip).map_err(|e| file_err(&ip, e.to_string()))?;
        let hdr = rd.headers().map_err(|e| file_err(&ip, e.to_string()))?.clone();
        let col = |n: &str| hdr.iter().position(|h| h.trim() == n);
        let need = |n: &str| col(n).ok_or_else(|| file_err(&ip, format!("missing column {n}")));
        let (cseq, ct, cimg) = (need("seq")?, need("t_s")?, need("image")?);
        let cc = [need("count1")?, need("count2")?, need("count3")?];
        let ccmd = ["cmd_alpha_deg", "cmd_beta_deg", "cmd_gamma_deg"].map(col);
        let cg = ["gx", "gy", "gz"].map(col);
        let mut rows: Vec<Row> = Vec::new();
        for (k, rec) in rd.records().enumerate() {
            let line = k + 2;
            let rec = rec.map_err(|e| file_err(&ip, format!("line {line}: {e}")))?;
            let field = |c: usize| rec.get(c).unwrap_or("").trim().to_string();
            let num = |c: usize, n: &str| -> Result<f64> {
                field(c).parse::<f64>().map_err(|_| file_err(&ip, format!("line {line}: column {n}: not a number")))
            };
            let int = |c: usize, n: &str| -> Result<i64> {
                field(c).parse::<i64>().map_err(|_| file_err(&ip, format!("line {line}: column {n}: not an integer")))
            };
            let opt3 = |cs: [Option<usize>; 3]| -> Result<Option<[f64; 3]>> {
                match cs {
                    [Some(a), Some(b), Some(c)] => Ok(Some([num(a, "cmd/g")?, num(b, "cmd/g")?, num(c, "cmd/g")?])),
                    _ => Ok(None),
                }
            };
            let seq = int(cseq, "seq")? as u64;
            if rows.last().is_some_and(|r| r.seq >= seq) {
                return Err(file_err(&ip, format!("line {line}: seq {seq} not increasing")));
            }
            rows.push(Row {
                seq,
                t_s: num(ct, "t_s")?,
                image: field(cimg),
                counts: [int(cc[0], "count1")?, int(cc[1], "count2")?, int(cc[2], "count3")?],
                cmd_deg: opt3(ccmd)?,
                gravity: opt3(cg)?,
            });
        }
        Ok(Session { dir: dir.to_path_buf(), meta, rows })
    }

    pub fn write(&self) -> Result<()> {
        std::fs::create_dir_all(&self.dir)?;
        let mp = self.dir.join("session.toml");
        let text = toml::to_string(&self.meta).map_err(|e| file_err(&mp, e.to_string()))?;
        std::fs::write(&mp, text)?;
        let ip = self.dir.join("index.csv");
        let mut w = csv::Writer::from_path(&ip).map_err(|e| file_err(&ip, e.to_string()))?;
        let with_cmd = self.rows.iter().all(|r| r.cmd_deg.is_some()) && !self.rows.is_empty();
        let with_g = self.rows.iter().all(|r| r.gravity.is_some()) && !self.rows.is_empty();
        let mut hdr = vec!["seq", "t_s", "image", "count1", "count2", "count3"];
        if with_cmd {
            hdr.extend(["cmd_alpha_deg", "cmd_beta_deg", "cmd_gamma_deg"]);
        }
        if with_g {
            hdr.extend(["gx", "gy", "gz"]);
        }
        let e = |e: csv::Error| file_err(&ip, e.to_string());
        w.write_record(&hdr).map_err(e)?;
        for r in &self.rows {
            let mut f = vec![r.seq.to_string(), format!("{}", r.t_s), r.image.clone()];
            f.extend(r.counts.iter().map(|c| c.to_string()));
            if with_cmd {
                f.extend(r.cmd_deg.unwrap_or_default().iter().map(|v| format!("{v}")));
            }
            if with_g {
                f.extend(r.gravity.unwrap_or_default().iter().map(|v| format!("{v}")));
            }
            w.write_record(&f).map_err(e)?;
        }
        w.flush()?;
        Ok(())
    }

    pub fn target(&self) -> Result<Target> {
        self.meta.target.parse()
    }

    pub fn camera(&self) -> Result<Camera> {
        let p = self.dir.join(&self.meta.camera);
        Camera::read_yaml(&p).map_err(|e| file_err(&p, e.to_string()))
    }

    /// Link angles (deg) of a row: 360 (count - home) / 92672.
    pub fn theta_deg(&self, r: &Row) -> [f64; 3] {
        std::array::from_fn(|i| 360.0 * (r.counts[i] - self.meta.home_counts[i]) as f64 / COUNTS_PER_REV as f64)
    }

    pub fn is_home(&self, r: &Row) -> bool {
        r.counts == self.meta.home_counts
    }
}

/// Encoder counts of link angles (deg) for given home counts (the inverse of
/// [`Session::theta_deg`], rounded to the count).
pub fn counts_of(theta_deg: &[f64; 3], home: &[i64; 3]) -> [i64; 3] {
    std::array::from_fn(|i| home[i] + (theta_deg[i] * COUNTS_PER_REV as f64 / 360.0).round() as i64)
}

/// What happened to each image of a measured session.
#[derive(Debug, Clone)]
pub struct MeasureReport {
    pub images: usize,
    pub measured: usize,
    /// (seq, image, why) of every image without a pose.
    pub failures: Vec<(u64, String, Failure)>,
    /// Per measured image: (seq, RMS reprojection px, corners used).
    pub per_image: Vec<(u64, f64, usize)>,
    pub rms_px: f64,
    pub home_images: usize,
    pub boards: Vec<u32>,
}

impl MeasureReport {
    /// Count of failures of each kind: unreadable, no board, too few corners, no pose.
    pub fn failure_counts(&self) -> [usize; 4] {
        let mut c = [0; 4];
        for (_, _, f) in &self.failures {
            c[match f {
                Failure::Unreadable(_) => 0,
                Failure::NoBoard => 1,
                Failure::TooFewCorners(_) => 2,
                Failure::NoPose(_) => 3,
            }] += 1;
        }
        c
    }
}

/// Measures a session: detects the corners in every image (on every core: [`detect_files`]), solves every
/// camera pose relative to home, and returns the dataset (rows in index order; failed images absent) and the
/// report. `progress(k, n)`: k of the n images detected, called from the detecting threads.
pub fn measure_session(
    s: &Session,
    detector: AprilDetector,
    opts: &SolveOptions,
    progress: impl Fn(usize, usize) + Sync,
) -> Result<(Dataset, MeasureReport, Solved)> {
    let target = s.target()?;
    let cam = s.camera()?;
    let n = s.rows.len();
    let files: Vec<PathBuf> = s.rows.iter().map(|r| s.dir.join(&r.image)).collect();
    let finished = std::sync::atomic::AtomicUsize::new(0);
    progress(0, n);
    let done = || progress(finished.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1, n);
    let dets: Vec<_> = detect_files(&files, &target, detector, &done)
        .into_iter()
        .map(|d| d.map_err(|e| Failure::Unreadable(e.to_string())))
        .collect();
    let home: Vec<bool> = s.rows.iter().map(|r| s.is_home(r)).collect();
    let solved = solve(&cam, &target, &dets, &home, opts)?;
    let mut samples = Vec::new();
    let mut failures = Vec::new();
    let mut per_image = Vec::new();
    for (i, r) in s.rows.iter().enumerate() {
        match &solved.poses[i] {
            Ok(p) => {
                let (rms, cnt) = solved.image_rms[i].unwrap_or((f64::NAN, 0));
                per_image.push((r.seq, rms, cnt));
                samples.push(Sample {
                    seq: r.seq,
                    t_s: r.t_s,
                    theta_deg: s.theta_deg(r),
                    pose: p.to_p6(),
                    cmd_deg: r.cmd_deg,
                    gravity: r.gravity,
                    extra: vec![format!("{rms:.4}"), cnt.to_string()],
                });
            }
            Err(f) => failures.push((r.seq, r.image.clone(), f.clone())),
        }
    }
    let report = MeasureReport {
        images: n,
        measured: samples.len(),
        failures,
        per_image,
        rms_px: solved.rms_px,
        home_images: home.iter().filter(|h| **h).count(),
        boards: solved.boards.keys().copied().collect(),
    };
    let ds = Dataset { samples, extra_columns: vec!["reproj_rms_px".into(), "n_corners".into()] };
    Ok((ds, report, solved))
}

pub const STEREO_FORMAT: &str = "abvs-stereo-session/1";

/// A stereo session at home: `DIR/stereo.toml` (format = "abvs-stereo-session/1", target,
/// model = "fisheye" | "pinhole" | "rational") and `DIR/pairs.csv` (columns left,right: image
/// paths relative to DIR, taken at the same instant, both eyes at home).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StereoMeta {
    pub format: String,
    pub target: String,
    pub model: String,
}

/// Reads a stereo session: metadata and the (left, right) image paths.
pub fn read_stereo_session(dir: &Path) -> Result<(StereoMeta, Vec<(PathBuf, PathBuf)>)> {
    let mp = dir.join("stereo.toml");
    let text = std::fs::read_to_string(&mp).map_err(|e| file_err(&mp, e.to_string()))?;
    let meta: StereoMeta = toml::from_str(&text).map_err(|e| file_err(&mp, e.to_string()))?;
    if meta.format != STEREO_FORMAT {
        return Err(file_err(&mp, format!("format '{}', expected '{STEREO_FORMAT}'", meta.format)));
    }
    let ip = dir.join("pairs.csv");
    let mut rd = csv::ReaderBuilder::new().from_path(&ip).map_err(|e| file_err(&ip, e.to_string()))?;
    let hdr = rd.headers().map_err(|e| file_err(&ip, e.to_string()))?.clone();
    let col =
        |n: &str| hdr.iter().position(|h| h.trim() == n).ok_or_else(|| file_err(&ip, format!("missing column {n}")));
    let (cl, cr) = (col("left")?, col("right")?);
    let mut pairs = Vec::new();
    for (k, rec) in rd.records().enumerate() {
        let rec = rec.map_err(|e| file_err(&ip, format!("line {}: {e}", k + 2)))?;
        let f = |c: usize| dir.join(rec.get(c).unwrap_or("").trim());
        pairs.push((f(cl), f(cr)));
    }
    Ok((meta, pairs))
}

/// Writes a stereo session's metadata and pair list (images already in `dir`).
pub fn write_stereo_session(dir: &Path, meta: &StereoMeta, pairs: &[(String, String)]) -> Result<()> {
    std::fs::create_dir_all(dir)?;
    let mp = dir.join("stereo.toml");
    std::fs::write(&mp, toml::to_string(meta).map_err(|e| file_err(&mp, e.to_string()))?)?;
    let ip = dir.join("pairs.csv");
    let mut w = csv::Writer::from_path(&ip).map_err(|e| file_err(&ip, e.to_string()))?;
    let e = |e: csv::Error| file_err(&ip, e.to_string());
    w.write_record(["left", "right"]).map_err(e)?;
    for (l, r) in pairs {
        w.write_record([l, r]).map_err(e)?;
    }
    w.flush()?;
    Ok(())
}
