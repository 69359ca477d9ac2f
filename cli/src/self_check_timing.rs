//! The eyes' timing from a self-check log: the encoder-to-camera offset (effects.md `encoder_time_offset`)
//! per eye and the rolling-shutter readout, fitted to the vertical disparities of the matched features.
//!
//! **The evidence** (`abvs_runtime::sinks::self_check`, module `timing`): the runtime reads each row's pose at
//! the time it believes the row exposed. Wrong by `eps` (used - true), the row is rectified with the eye
//! turned by `omega eps`, and every match's vertical disparity moves by `s_l eps_l + s_r eps_r` (px; the log
//! holds `s_l`, `s_r` per match). Offsets wrong by `dT_k` and a readout wrong by `dR` give, at raw row
//! fraction `rho` (0 = top), `eps_k = dT_k + dR (rho - anchor)`; `anchor` is the row the frames' stamps fix.
//! The eyes' *difference* of angular velocity (vergence) turns a time error into a relative rotation of the
//! cameras; their common motion (pursuit) into a common rotation, which tilts the baseline in the images (a
//! vertical disparity proportional to the horizontal one). Each eye's offset is observable when the eyes
//! both pursue and verge; the readout is fitted as one value for both cameras, which are the same sensor in
//! the same mode, started together (conventions.md "Time": rows of the same index expose together).
//!
//! **The fit.** Least squares with Huber weights (k = 1.345 robust sigmas) of `dy = j w + s_l eps_l + s_r
//! eps_r` over the matches of the frames where the eyes moved steadily (`steady`): `w` is the static stereo
//! rotation error (the self-check's, 3 parameters), the time errors are parametrised at the middle row
//! (`tau_k = eps_k(1/2)`) and by `dR`, which decorrelates them. Sigmas are cluster-robust over frames (a
//! frame's matches share its FK error), so they hold the frame-to-frame calibration error too. The model is
//! first order in `omega eps`: far from the truth (a readout off by 25 ms at 90 deg/s turns rows by a
//! degree) it only points the way. So it goes in rounds: the run is repeated with the estimate and fitted
//! again (the log records the timing each run applied, so each fit is a correction to it) while the
//! correction is larger than the accuracy asked and twice its sigma (`refine`). A log of a replay carries its
//! configuration (`<log>.run.toml`), and `abvs calib self-check` re-runs that replay itself (`--rounds`, 3 by
//! default); a live log asks for another minute of motion with the new values.
//!
//! **Held out.** The frames alternate into two halves; each half's model predicts the other's matches. The
//! improvement is the fraction of the held-out residual (RMS, px) the timing terms remove beyond the static
//! rotation. The alternative: a pose error along the direction of motion that does not grow with speed
//! (backlash, a settling mechanism): the same terms divided by the speed. When it predicts as well, speed
//! does not tell them apart and the report says so.
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use abvs_runtime_core::config::{RuntimeConfig, SourceKind};
use abvs_runtime_core::session::TimeOffsetMs;
use anyhow::{bail, Context};
use nalgebra::{DMatrix, DVector};
use serde_json::{json, Value};

/// One logged frame's timing context.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameTiming {
    /// Pipeline sequence number.
    pub seq: u64,
    /// Each camera's angular speed (deg/s).
    pub speed: [f64; 2],
    /// Change of each camera's mean angular velocity across the frame instant (deg/s).
    pub accel: [f64; 2],
    /// The readout the run applied (ms).
    pub readout_ms: f64,
    /// The row fraction the stamps fix.
    pub anchor: f64,
    /// The encoder offsets the run applied (ms).
    pub offset_ms: [f64; 2],
    /// |rotation error| the self-check measured on the frame (deg); NaN without a fit.
    pub error_deg: f64,
    /// Row bands of the rolling-shutter correction (0: the frame corrected as a whole); NaN in older logs.
    pub row_bands: f64,
    /// The run's identity (`run_id`); NaN in older logs.
    pub run_id: f64,
}

/// One match's timing evidence (the runtime's match log).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchEvidence {
    /// The frame.
    pub seq: u64,
    /// Raw row fraction of the left and right point.
    pub row: [f64; 2],
    /// Vertical disparity (px).
    pub dy: f64,
    /// Design row of the static rotation (px/rad).
    pub j: [f64; 3],
    /// d(dy)/d(eps) per eye (px/ms).
    pub s: [f64; 2],
    /// Parallax of each camera's optical centre moving for a millisecond (px/ms).
    pub u: [f64; 2],
}

fn number(path: &Path, rec: &csv::StringRecord, line: usize, k: usize, name: &str) -> anyhow::Result<f64> {
    let s = rec.get(k).unwrap_or("").trim();
    if s.is_empty() {
        return Ok(f64::NAN);
    }
    s.parse().with_context(|| format!("{}:{line}: `{name}`: `{s}` is not a number", path.display()))
}

/// The columns `names` of a CSV file, per record (its line, the values; an empty field is NaN). `None` when
/// a column is missing and `optional`; an error naming it otherwise.
fn read_columns(path: &Path, names: &[&str], optional: bool) -> anyhow::Result<Option<Vec<(usize, Vec<f64>)>>> {
    let mut rd = csv::Reader::from_path(path).with_context(|| format!("reading {}", path.display()))?;
    let head = rd.headers()?.clone();
    let mut idx = Vec::with_capacity(names.len());
    for n in names {
        match head.iter().position(|h| h == *n) {
            Some(k) => idx.push(k),
            None if optional => return Ok(None),
            None => bail!("{}: no column `{n}`", path.display()),
        }
    }
    let mut out = Vec::new();
    for (i, rec) in rd.records().enumerate() {
        let line = i + 2;
        let rec = rec.with_context(|| format!("{}:{line}: unreadable record", path.display()))?;
        let v = idx.iter().zip(names).map(|(&k, n)| number(path, &rec, line, k, n)).collect::<anyhow::Result<_>>()?;
        out.push((line, v));
    }
    Ok(Some(out))
}

/// The per-frame log's timing columns (`None` when the log predates them).
pub fn read_frames(path: &Path) -> anyhow::Result<Option<Vec<FrameTiming>>> {
    let names = [
        "seq",
        "speed_l_deg_s",
        "speed_r_deg_s",
        "accel_l_deg_s",
        "accel_r_deg_s",
        "readout_ms",
        "readout_anchor",
        "offset_l_ms",
        "offset_r_ms",
        "rot_x_deg",
        "rot_y_deg",
        "rot_z_deg",
    ];
    let Some(rows) = read_columns(path, &names, true)? else { return Ok(None) };
    let mut out = Vec::with_capacity(rows.len());
    for (line, v) in rows {
        if !(v[0] >= 0.0) || v[1..9].iter().any(|x| !x.is_finite()) {
            bail!("{}:{line}: timing fields (seq, speeds, readout, offsets) must be numbers", path.display());
        }
        out.push(FrameTiming {
            seq: v[0] as u64,
            speed: [v[1], v[2]],
            accel: [v[3], v[4]],
            readout_ms: v[5],
            anchor: v[6],
            offset_ms: [v[7], v[8]],
            error_deg: (v[9] * v[9] + v[10] * v[10] + v[11] * v[11]).sqrt(),
            row_bands: f64::NAN,
            run_id: f64::NAN,
        });
    }
    // the run's identity and what its correction did (logs written before them lack the columns)
    if let Some(extra) = read_columns(path, &["row_bands", "run_id"], true)? {
        for (f, (_, v)) in out.iter_mut().zip(extra) {
            (f.row_bands, f.run_id) = (v[0], v[1]);
        }
    }
    Ok(Some(out))
}

/// The one run identity of a log's rows (`None`: the log predates it); an error when its rows mix runs.
pub fn run_id_of(path: &Path, ids: impl Iterator<Item = f64>) -> anyhow::Result<Option<u64>> {
    let mut one = None;
    for id in ids.filter(|x| x.is_finite()) {
        match one {
            None => one = Some(id),
            Some(o) if o != id => bail!("{}: rows of two runs ({o} and {id}): one log, one run", path.display()),
            _ => {}
        }
    }
    Ok(one.map(|x| x as u64))
}

/// The run a `<log>.run.toml` names (its `# self-check run_id = N` line; `None` in older files).
fn run_id_of_config(path: &Path) -> anyhow::Result<Option<u64>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let Some(rest) = text.lines().find_map(|l| l.strip_prefix("# self-check run_id = ")) else { return Ok(None) };
    Ok(Some(rest.trim().parse().with_context(|| format!("{}: run_id `{rest}` is not a number", path.display()))?))
}

/// The match log (`<log>.matches.csv`) and the run it names (`None` in older logs).
pub fn read_matches_of_run(path: &Path) -> anyhow::Result<(Vec<MatchEvidence>, Option<u64>)> {
    let m = read_matches(path)?;
    let ids = read_columns(path, &["run_id"], true)?.unwrap_or_default();
    Ok((m, run_id_of(path, ids.into_iter().map(|(_, v)| v[0]))?))
}

/// Refuses a match log of another run than its frame log, naming both.
fn same_run(log: &Path, frames: &[FrameTiming], mpath: &Path, mrun: Option<u64>) -> anyhow::Result<Option<u64>> {
    let run = run_id_of(log, frames.iter().map(|f| f.run_id))?;
    if let (Some(a), Some(b)) = (run, mrun) {
        if a != b {
            bail!(
                "{} is of run {b}, the frame log {} of run {a}: logs of different runs (each `abvs run \
                 --self-check-log` writes both; keep them together)",
                mpath.display(),
                log.display()
            );
        }
    }
    Ok(run)
}

/// Why the log's run cannot be fitted as it was applied: frames the rolling-shutter correction left whole
/// although the cameras have a readout (the fit models a per-row correction).
fn not_as_applied(frames: &[FrameTiming]) -> Option<String> {
    let whole = frames.iter().filter(|f| f.row_bands == 0.0 && f.readout_ms > 0.0 && steady(f)).count();
    (whole > 0).then(|| {
        format!(
            "the run rectified {whole} moving frames as a whole, at their instant (the rolling-shutter correction \
             was off: `--rolling-shutter off`, `[motion] rolling_shutter = false`), while the fit models a run that \
             reads each row at its own time: replay with the correction on and fit that log"
        )
    })
}

/// The match log (`<log>.matches.csv`).
pub fn read_matches(path: &Path) -> anyhow::Result<Vec<MatchEvidence>> {
    let names = [
        "seq",
        "row_l",
        "row_r",
        "dy_px",
        "j_x",
        "j_y",
        "j_z",
        "s_l_px_per_ms",
        "s_r_px_per_ms",
        "u_l_px_per_ms",
        "u_r_px_per_ms",
    ];
    let rows = read_columns(path, &names, false)?.unwrap_or_default();
    let mut out = Vec::with_capacity(rows.len());
    for (line, v) in rows {
        if let Some(k) = v.iter().position(|x| !x.is_finite()) {
            bail!("{}:{line}: `{}` must be a number", path.display(), names[k]);
        }
        if v[0] < 0.0 {
            bail!("{}:{line}: `seq` must not be negative", path.display());
        }
        out.push(MatchEvidence {
            seq: v[0] as u64,
            row: [v[1], v[2]],
            dy: v[3],
            j: [v[4], v[5], v[6]],
            s: [v[7], v[8]],
            u: [v[9], v[10]],
        });
    }
    Ok(out)
}

/// A value and its 1-sigma.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Est {
    /// The estimate.
    pub value: f64,
    /// Its standard deviation.
    pub sigma: f64,
}

impl Est {
    fn json(&self) -> Value {
        let r = |x: f64| (x * 1e4).round() / 1e4;
        json!({ "value": r(self.value), "sigma": r(self.sigma) })
    }
    /// |value| beyond `k` sigmas.
    pub fn significant(&self, k: f64) -> bool {
        self.value.abs() > k * self.sigma
    }
}

/// The timing a log's matches say the eyes have.
#[derive(Debug, Clone)]
pub struct TimingFit {
    /// encoder_time_offset per eye (ms), absolute (what to apply).
    pub offset: [Est; 2],
    /// Their mean.
    pub offset_common: Est,
    /// Right minus left.
    pub offset_difference: Est,
    /// Readout of both cameras (ms), absolute.
    pub readout: Est,
    /// Corrections to what the run applied (ms): offsets per eye and readout (applied - true).
    pub correction: [Est; 3],
    /// What the run applied: offsets per eye, readout (ms).
    pub applied: [f64; 3],
    /// Frames used (steady motion) of those logged with matches, and matches used.
    pub frames: (usize, usize),
    /// Matches used.
    pub matches: usize,
    /// Robust residual scale (px).
    pub scale_px: f64,
    /// Held-out residual (RMS px) with the static rotation only, with the timing, and with the alternative.
    pub heldout_rms: [f64; 3],
    /// Peak eye speed among the frames used (deg/s).
    pub max_speed: f64,
}

impl TimingFit {
    /// Held-out fraction of the residual the timing removes (1 - with / without).
    pub fn improvement(&self) -> f64 {
        1.0 - self.heldout_rms[1] / self.heldout_rms[0]
    }
    /// The same for the alternative (a speed-independent error along the motion).
    pub fn alternative_improvement(&self) -> f64 {
        1.0 - self.heldout_rms[2] / self.heldout_rms[0]
    }
    /// Whether a correction is large against its sigma and the accuracy asked of it (0.3 ms of offset, 2 ms
    /// of readout): worth another round.
    pub fn refine(&self) -> bool {
        let big = |e: &Est, floor: f64| e.value.abs() > floor.max(2.0 * e.sigma);
        big(&self.correction[0], 0.3) || big(&self.correction[1], 0.3) || big(&self.correction[2], 2.0)
    }
    /// summary.json's `timing`.
    pub fn json(&self) -> Value {
        let mut offset = self.offset_common.json();
        offset["left"] = self.offset[0].json();
        offset["right"] = self.offset[1].json();
        offset["difference_right_minus_left"] = self.offset_difference.json();
        json!({
            "encoder_time_offset_ms": offset,
            "readout_ms": self.readout.json(),
            "applied": { "offset_ms": [self.applied[0], self.applied[1]], "readout_ms": self.applied[2] },
            "correction_ms": {
                "offset_left": self.correction[0].json(),
                "offset_right": self.correction[1].json(),
                "readout": self.correction[2].json(),
            },
            "frames_used": self.frames.0,
            "frames_logged": self.frames.1,
            "matches_used": self.matches,
            "residual_scale_px": (self.scale_px * 1e4).round() / 1e4,
            "max_speed_deg_s": (self.max_speed * 10.0).round() / 10.0,
            "heldout_rms_px": {
                "static_rotation": self.heldout_rms[0],
                "with_timing": self.heldout_rms[1],
                "alternative_speed_independent": self.heldout_rms[2],
            },
            "heldout_improvement": self.improvement(),
            "alternative_improvement": self.alternative_improvement(),
            "refine": self.refine(),
        })
    }
}

/// A frame's motion was steady enough for the first-order model: its mean angular velocity changed by at
/// most a quarter of its speed across the instant (or by 2 deg/s when slower than 8 deg/s).
pub fn steady(f: &FrameTiming) -> bool {
    (0..2).all(|e| f.accel[e] <= (0.25 * f.speed[e]).max(2.0))
}

/// Which design: the timing terms (per-eye mid-row offset, readout), or the alternative (the same terms
/// divided by the eye's speed: an error along the motion whose size does not grow with speed), or none.
#[derive(Clone, Copy, PartialEq)]
enum Terms {
    Static,
    Timing,
    Alternative,
}

fn design_row(m: &MatchEvidence, f: &FrameTiming, terms: Terms) -> Vec<f64> {
    let mut x = vec![m.j[0], m.j[1], m.j[2]];
    match terms {
        Terms::Static => {}
        Terms::Timing => {
            x.push(m.s[0]);
            x.push(m.s[1]);
            // the readout error turns the rows (s) and changes the parallax the rows keep (-u, see `observed`)
            x.push((m.s[0] - m.u[0]) * (m.row[0] - 0.5) + (m.s[1] - m.u[1]) * (m.row[1] - 0.5));
        }
        Terms::Alternative => {
            let sl = m.s[0] / f.speed[0].max(1.0) * 30.0;
            let sr = m.s[1] / f.speed[1].max(1.0) * 30.0;
            x.push(sl);
            x.push(sr);
            x.push(sl * (m.row[0] - 0.5) + sr * (m.row[1] - 0.5));
        }
    }
    x
}

/// The vertical disparity less the parallax the per-row correction leaves with the applied readout: a row
/// read `(rho - 1/2) R` from the instant has its camera centre moved by the velocity times that (the correction
/// turns rows, it does not move them), `u (rho - 1/2) R_true` px, and `R_true = R_applied - dR`.
fn observed(m: &MatchEvidence, f: &FrameTiming) -> f64 {
    m.dy - (m.u[0] * (m.row[0] - 0.5) + m.u[1] * (m.row[1] - 0.5)) * f.readout_ms
}

struct Fitted {
    beta: DVector<f64>,
    cov: DMatrix<f64>,
    scale: f64,
}

/// IRLS with Huber weights; covariance cluster-robust over frames.
fn irls(rows: &[(Vec<f64>, f64, u64)]) -> Option<Fitted> {
    let k = rows.first()?.0.len();
    if rows.len() < 4 * k {
        return None;
    }
    let mut w = vec![1.0; rows.len()];
    let mut beta = DVector::zeros(k);
    let mut scale = 1.0;
    let mut ata = DMatrix::zeros(k, k);
    for it in 0..30 {
        ata = DMatrix::zeros(k, k);
        let mut atb = DVector::zeros(k);
        for ((x, y, _), wt) in rows.iter().zip(&w) {
            let xv = DVector::from_column_slice(x);
            ata += &xv * xv.transpose() * *wt;
            atb += xv * (*y * *wt);
        }
        let next = ata.clone().try_inverse()? * atb;
        let res: Vec<f64> = rows.iter().map(|(x, y, _)| y - DVector::from_column_slice(x).dot(&next)).collect();
        let mut abs: Vec<f64> = res.iter().map(|r| r.abs()).collect();
        abs.sort_by(f64::total_cmp);
        scale = (1.4826 * abs[abs.len() / 2]).max(1e-4);
        let kh = 1.345 * scale;
        for (wt, r) in w.iter_mut().zip(&res) {
            *wt = if r.abs() <= kh { 1.0 } else { kh / r.abs() };
        }
        let step = (&next - &beta).norm();
        beta = next;
        if it > 0 && step < 1e-9 * (1.0 + beta.norm()) {
            break;
        }
    }
    let inv = ata.try_inverse()?;
    let mut meat = DMatrix::zeros(k, k);
    let mut by_frame: BTreeMap<u64, DVector<f64>> = BTreeMap::new();
    for ((x, y, seq), wt) in rows.iter().zip(&w) {
        let xv = DVector::from_column_slice(x);
        let r = y - xv.dot(&beta);
        *by_frame.entry(*seq).or_insert_with(|| DVector::zeros(k)) += xv * (r * wt);
    }
    let g = by_frame.len() as f64;
    for s in by_frame.values() {
        meat += s * s.transpose();
    }
    let cov = &inv * meat * &inv * if g > 1.0 { g / (g - 1.0) } else { f64::INFINITY };
    Some(Fitted { beta, cov, scale })
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

/// Fits the timing to a log's frames and matches. `None` when too few steady frames with matches moved.
pub fn fit(frames: &[FrameTiming], matches: &[MatchEvidence]) -> anyhow::Result<Option<TimingFit>> {
    let by_seq: BTreeMap<u64, &FrameTiming> = frames.iter().map(|f| (f.seq, f)).collect();
    let first = match frames.first() {
        Some(f) => *f,
        None => return Ok(None),
    };
    if let Some(f) = frames
        .iter()
        .find(|f| f.readout_ms != first.readout_ms || f.offset_ms != first.offset_ms || f.anchor != first.anchor)
    {
        bail!(
            "frame {}: the log's timing changed during the run (readout {} ms, offsets {:?} ms; first frame: {} ms, \
             {:?} ms): one log, one timing",
            f.seq,
            f.readout_ms,
            f.offset_ms,
            first.readout_ms,
            first.offset_ms
        );
    }
    let mut logged = std::collections::BTreeSet::new();
    let mut used: Vec<(&MatchEvidence, &FrameTiming)> = Vec::new();
    for m in matches {
        let Some(f) = by_seq.get(&m.seq) else {
            bail!("match log: frame {} is not in the frame log (logs of different runs?)", m.seq);
        };
        logged.insert(m.seq);
        if steady(f) {
            used.push((m, f));
        }
    }
    let seqs: std::collections::BTreeSet<u64> = used.iter().map(|(m, _)| m.seq).collect();
    let max_speed = seqs.iter().map(|s| by_seq[s].speed[0].max(by_seq[s].speed[1])).fold(0.0, f64::max);
    if seqs.len() < 10 || max_speed < 5.0 {
        return Ok(None);
    }
    let rows = |terms: Terms, keep: &dyn Fn(u64) -> bool| -> Vec<(Vec<f64>, f64, u64)> {
        used.iter()
            .filter(|(m, _)| keep(m.seq))
            .map(|(m, f)| (design_row(m, f, terms), observed(m, f), m.seq))
            .collect()
    };
    let Some(full) = irls(&rows(Terms::Timing, &|_| true)) else { return Ok(None) };
    // held out: alternate frames
    let order: Vec<u64> = seqs.iter().copied().collect();
    let half = |s: u64| order.binary_search(&s).map(|i| i % 2).unwrap_or(0);
    let mut heldout = [Vec::new(), Vec::new(), Vec::new()];
    for h in 0..2 {
        for (t, terms) in [Terms::Static, Terms::Timing, Terms::Alternative].into_iter().enumerate() {
            let Some(fit) = irls(&rows(terms, &|s| half(s) != h)) else { return Ok(None) };
            for (x, y, _) in rows(terms, &|s| half(s) == h) {
                heldout[t].push(y - DVector::from_column_slice(&x).dot(&fit.beta));
            }
        }
    }
    // robust RMS: the residuals within 3 robust sigmas of the static model's (outlier matches excluded alike)
    let mut abs0: Vec<f64> = heldout[0].iter().map(|r| r.abs()).collect();
    abs0.sort_by(f64::total_cmp);
    let cut = 3.0 * 1.4826 * abs0[abs0.len() / 2];
    let inlier: Vec<bool> = heldout[0].iter().map(|r| r.abs() <= cut).collect();
    let heldout_rms = [0, 1, 2]
        .map(|t| rms(&heldout[t].iter().zip(&inlier).filter(|(_, k)| **k).map(|(r, _)| *r).collect::<Vec<_>>()));

    let (b, c) = (&full.beta, &full.cov);
    let a = 0.5 - first.anchor;
    // eps_k(rho) = tau_k + dR (rho - 1/2) = dT_k + dR (rho - anchor): dT_k = tau_k - dR (1/2 - anchor)
    let lin = |coef: &[(usize, f64)]| -> Est {
        let value = coef.iter().map(|(i, a)| a * b[*i]).sum();
        let var: f64 = coef.iter().flat_map(|(i, a)| coef.iter().map(move |(j, bb)| a * bb * c[(*i, *j)])).sum();
        Est { value, sigma: var.max(0.0).sqrt() }
    };
    let d_left = lin(&[(3, 1.0), (5, -a)]);
    let d_right = lin(&[(4, 1.0), (5, -a)]);
    let d_common = lin(&[(3, 0.5), (4, 0.5), (5, -a)]);
    let d_readout = lin(&[(5, 1.0)]);
    let diff = lin(&[(4, 1.0), (3, -1.0)]);
    let abs = |applied: f64, d: Est| Est { value: applied - d.value, sigma: d.sigma };
    let applied_common = 0.5 * (first.offset_ms[0] + first.offset_ms[1]);
    Ok(Some(TimingFit {
        offset: [abs(first.offset_ms[0], d_left), abs(first.offset_ms[1], d_right)],
        offset_common: abs(applied_common, d_common),
        offset_difference: Est { value: (first.offset_ms[1] - first.offset_ms[0]) - diff.value, sigma: diff.sigma },
        readout: abs(first.readout_ms, d_readout),
        correction: [d_left, d_right, d_readout],
        applied: [first.offset_ms[0], first.offset_ms[1], first.readout_ms],
        frames: (seqs.len(), logged.len()),
        matches: used.len(),
        scale_px: full.scale,
        heldout_rms,
        max_speed,
    }))
}

/// What the timing analysis adds to `abvs calib self-check`'s outputs.
pub struct Analysis {
    /// summary.json's `timing` (null with a `reason` when there is no estimate).
    pub json: Value,
    /// The report's timing section.
    pub markdown: String,
    /// Lines for the console.
    pub console: Vec<String>,
    /// error_by_speed.png was written.
    pub plotted: bool,
    /// The writes of the estimate (--write-config, --write-session) that failed: reported after report.md and
    /// summary.json are written, so a failure at the end loses no result.
    pub failed_writes: Vec<String>,
}

/// Every file `calib self-check` will write or edit, checked before any work (the replay rounds take
/// minutes): --out can be made, --write-config is an existing, writable TOML file, --write-session is a
/// session whose session.toml is one.
pub fn check_outputs(a: &crate::self_check_report::SelfCheckArgs) -> anyhow::Result<()> {
    abvs_runtime::outputs::check_dir_creatable("--out", &a.out)?;
    let editable = |flag: &str, p: &Path, what: &str| -> anyhow::Result<()> {
        if !p.is_file() {
            bail!("{flag} {}: no such file ({what})", p.display());
        }
        let text = std::fs::read_to_string(p).with_context(|| format!("{flag} {}: reading it", p.display()))?;
        text.parse::<toml_edit::DocumentMut>()
            .with_context(|| format!("{flag} {}: not a TOML document", p.display()))?;
        std::fs::OpenOptions::new()
            .append(true)
            .open(p)
            .with_context(|| format!("{flag} {}: not writable", p.display()))?;
        Ok(())
    };
    if let Some(p) = &a.write_config {
        editable(
            "--write-config",
            p,
            "the configuration to edit must exist: `abvs run --print-config > FILE` writes one",
        )?;
    }
    if let Some(d) = &a.write_session {
        editable("--write-session", &d.join("session.toml"), "expected a session directory")?;
    }
    Ok(())
}

/// Smallest offset (ms) and readout (ms) named as an effect: below them the fit's first-order bias (a few
/// tenths of a millisecond of offset, about a millisecond of readout on rendered sessions with the true
/// timing applied) could name an effect that is not there.
const MIN_OFFSET_MS: f64 = 0.2;
const MIN_READOUT_MS: f64 = 2.0;

fn round2(x: f64) -> f64 {
    (x * 100.0).round() / 100.0
}

/// The timing setting of an estimate: one offset, or one per eye when they differ beyond three sigmas.
fn offset_setting(t: &TimingFit) -> TimeOffsetMs {
    if t.offset_difference.significant(3.0) && t.offset_difference.value.abs() >= MIN_OFFSET_MS {
        TimeOffsetMs::PerEye([round2(t.offset[0].value), round2(t.offset[1].value)])
    } else {
        TimeOffsetMs::Both(round2(t.offset_common.value))
    }
}

/// The offset setting as a TOML value.
fn offset_item(t: &TimingFit) -> toml_edit::Item {
    match offset_setting(t) {
        TimeOffsetMs::PerEye([l, r]) => {
            let mut arr = toml_edit::Array::new();
            arr.push(l);
            arr.push(r);
            toml_edit::value(arr)
        }
        TimeOffsetMs::Both(v) => toml_edit::value(v),
    }
}

/// The configuration a log's run used (`<log>.run.toml`), when it replayed a session that is still there and
/// names the log's run; otherwise why the rounds cannot run.
fn replay_config(log: &Path, run: Option<u64>) -> anyhow::Result<Result<RuntimeConfig, String>> {
    let p = abvs_runtime::sinks::self_check::run_config_path(log);
    if !p.exists() {
        return Ok(Err(format!("no {} beside the log (its run's configuration): nothing to replay", p.display())));
    }
    if let (Some(a), Some(b)) = (run, run_id_of_config(&p)?) {
        if a != b {
            return Ok(Err(format!(
                "{} is of run {b}, the log of run {a}: not replayed (another run's configuration)",
                p.display()
            )));
        }
    }
    let c = RuntimeConfig::load(&p)?;
    if c.source.kind != SourceKind::Session {
        return Ok(Err(format!("{}: a live run, not a replay: record another minute with the estimate", p.display())));
    }
    match c.source.session.as_deref() {
        Some(d) if d.join("session.toml").exists() => Ok(Ok(c)),
        d => Ok(Err(format!(
            "{}: its session {} is not there any more",
            p.display(),
            d.map_or("(none)".into(), |d| d.display().to_string())
        ))),
    }
}

/// Replays `cfg`'s session with `t`'s timing, lossless, nothing published, the self-check logging to `log`.
fn rerun(cfg: &RuntimeConfig, t: &TimingFit, log: &Path) -> anyhow::Result<()> {
    let mut c = cfg.clone();
    c.motion.time_offset_ms = Some(offset_setting(t));
    c.motion.readout_ms = Some(round2(t.readout.value.max(0.0)));
    c.source.lossless = true;
    c.source.paced = false;
    c.bridges.iceoryx.enabled = false;
    c.bridges.zenoh.enabled = false;
    c.sinks.mcap.file = None;
    c.sinks.stats_json = None;
    c.sinks.dump = None;
    c.sinks.rerun = None;
    c.sinks.quiet = true;
    c.sinks.self_check.enabled = true;
    c.sinks.self_check.log = Some(log.to_path_buf());
    abvs_runtime::Runtime::from_config(&c)?.run()?;
    Ok(())
}

fn edit_toml(path: &Path, table: Option<&str>, t: &TimingFit) -> anyhow::Result<()> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let mut doc: toml_edit::DocumentMut =
        text.parse().with_context(|| format!("{}: not a TOML document", path.display()))?;
    let tab = match table {
        Some(name) => {
            let item = doc.entry(name).or_insert(toml_edit::table());
            item.as_table_mut().with_context(|| format!("{}: `{name}` is not a table", path.display()))?
        }
        None => doc.as_table_mut(),
    };
    tab.insert("time_offset_ms", offset_item(t));
    tab.insert("readout_ms", toml_edit::value(round2(t.readout.value.max(0.0))));
    std::fs::write(path, doc.to_string()).with_context(|| format!("writing {}", path.display()))
}

/// Median |rotation error| (deg) of the frames in each speed band: the curve of error_by_speed.png.
fn error_by_speed(frames: &[FrameTiming]) -> Vec<(f64, f64)> {
    const EDGES: [f64; 8] = [0.0, 5.0, 15.0, 30.0, 50.0, 75.0, 100.0, 160.0];
    let mut out = Vec::new();
    for w in EDGES.windows(2) {
        let mut v: Vec<f64> = frames
            .iter()
            .filter(|f| f.error_deg.is_finite())
            .filter(|f| (w[0]..w[1]).contains(&f.speed[0].max(f.speed[1])))
            .map(|f| f.error_deg)
            .collect();
        if v.len() >= 2 {
            v.sort_by(f64::total_cmp);
            out.push((0.5 * (w[0] + w[1]), 0.5 * (v[(v.len() - 1) / 2] + v[v.len() / 2])));
        }
    }
    out
}

/// Estimates the timing from the log (and its match log), writes error_by_speed.png and, when asked, the
/// estimate into a configuration and a session.
pub fn analyse(a: &crate::self_check_report::SelfCheckArgs, label: &str) -> anyhow::Result<Analysis> {
    let none = |reason: String| Analysis {
        json: json!({ "reason": reason }),
        markdown: format!("\n## Timing\n\nNo estimate: {reason}.\n"),
        console: vec![format!("timing: no estimate: {reason}")],
        plotted: false,
        failed_writes: Vec::new(),
    };
    let Some(frames) = read_frames(&a.log)? else {
        return Ok(none("the log has no timing columns (written by an abvs before the timing evidence)".into()));
    };
    let before = match &a.before {
        Some(p) => Some(read_frames(p)?.with_context(|| format!("{}: no timing columns", p.display()))?),
        None => None,
    };
    let plot = |logs: &[(PathBuf, Vec<FrameTiming>)]| -> anyhow::Result<bool> {
        let labels: Vec<String> =
            (0..logs.len()).map(|k| if k == 0 { label.to_string() } else { format!("after round {k}") }).collect();
        let mut series = Vec::new();
        if let Some(b) = &before {
            series.push(abvs_plot::Series {
                label: "before",
                points: error_by_speed(b),
                style: abvs_plot::SeriesStyle::LinePoints,
            });
        }
        for ((_, f), l) in logs.iter().zip(&labels) {
            series.push(abvs_plot::Series {
                label: l,
                points: error_by_speed(f),
                style: abvs_plot::SeriesStyle::LinePoints,
            });
        }
        if series.iter().all(|s| s.points.is_empty()) {
            return Ok(false);
        }
        abvs_plot::xy_plot(
            &a.out.join("error_by_speed.png"),
            &abvs_plot::XyPlot {
                title: "self-check rotation error against eye speed (median per band)",
                x_label: "faster eye's speed, deg/s",
                y_label: "|rotation error|, deg",
                series,
                log_y: false,
            },
        )?;
        Ok(true)
    };
    let mut logs = vec![(a.log.clone(), frames.clone())];
    let mpath = abvs_runtime::sinks::self_check::match_log_path(&a.log);
    if !mpath.exists() {
        let mut r = none(format!("no match log {} (the run had no raw cameras for the evidence)", mpath.display()));
        r.plotted = plot(&logs)?;
        return Ok(r);
    }
    let (matches, mrun) = read_matches_of_run(&mpath)?;
    let run = same_run(&a.log, &frames, &mpath, mrun)?;
    if let Some(why) = not_as_applied(&frames) {
        let mut r = none(why);
        r.plotted = plot(&logs)?;
        return Ok(r);
    }
    let Some(first) = fit(&frames, &matches)? else {
        let mut r = none(
            "too few frames in which the eyes moved steadily (at least 10 with matches, faster than 5 deg/s): \
             record a minute of pursuit with the eyes verging"
                .into(),
        );
        r.plotted = plot(&logs)?;
        return Ok(r);
    };
    // rounds: a replay is run again with the estimate and fitted again while the correction is large
    let mut fits = vec![first];
    let mut no_rounds = None;
    let replay = if a.rounds > 0 && fits[0].refine() {
        match replay_config(&a.log, run)? {
            Ok(c) => Some(c),
            Err(why) => {
                no_rounds = Some(why);
                None
            }
        }
    } else {
        None
    };
    if let Some(cfg) = &replay {
        for k in 1..=a.rounds {
            let prev = fits.last().expect("one fit");
            if !prev.refine() {
                break;
            }
            let log = a.out.join(format!("round-{k}.csv"));
            // what the round applies, as the replay reads it (per eye where the estimate is per eye)
            let applied = match offset_setting(prev) {
                TimeOffsetMs::Both(v) => format!("offset {v:.2} ms (both eyes)"),
                TimeOffsetMs::PerEye([l, r]) => format!("offsets {l:.2} ms left, {r:.2} ms right"),
            };
            eprintln!(
                "timing: round {k}: replaying {} with {applied}, readout {:.2} ms",
                cfg.source.session.as_deref().unwrap_or(Path::new("?")).display(),
                round2(prev.readout.value.max(0.0))
            );
            rerun(cfg, prev, &log)?;
            let frames = read_frames(&log)?.with_context(|| format!("{}: no timing columns", log.display()))?;
            let mp = abvs_runtime::sinks::self_check::match_log_path(&log);
            let (matches, mrun) = read_matches_of_run(&mp)?;
            same_run(&log, &frames, &mp, mrun)?;
            let Some(t) = fit(&frames, &matches)? else { break };
            fits.push(t);
            logs.push((log, frames));
        }
    }
    let plotted = plot(&logs)?;
    let t = fits.last().expect("one fit").clone();
    let first = &fits[0];
    let named_offset = t.offset_common.significant(3.0) && t.offset_common.value.abs() >= MIN_OFFSET_MS;
    let named_readout = t.readout.significant(3.0) && t.readout.value.abs() >= MIN_READOUT_MS;
    let per_eye = t.offset_difference.significant(3.0) && t.offset_difference.value.abs() >= MIN_OFFSET_MS;
    let e = |x: &Est| format!("{:.2} ± {:.2}", x.value, x.sigma);
    let mut md = String::from("\n## Timing\n\n");
    md += &format!(
        "Fitted to {} matches of {} frames in which the eyes moved steadily (of {} checked; fastest {:.0} deg/s), \
         residual scale {:.3} px. The run applied offsets {:.2} / {:.2} ms (left / right) and a readout of {:.2} \
         ms.\n\n",
        t.matches, t.frames.0, t.frames.1, t.max_speed, t.scale_px, t.applied[0], t.applied[1], t.applied[2]
    );
    md += "| effect | estimate (ms) | applied (ms) | correction (ms) | named |\n|---|---|---|---|---|\n";
    md += &format!(
        "| encoder_time_offset, both eyes | {} | {:.2} | | {} |\n",
        e(&t.offset_common),
        0.5 * (t.applied[0] + t.applied[1]),
        if named_offset { "yes" } else { "no" }
    );
    for (k, side) in ["left", "right"].iter().enumerate() {
        md += &format!(
            "| encoder_time_offset, {side} | {} | {:.2} | {} | {} |\n",
            e(&t.offset[k]),
            t.applied[k],
            e(&Est { value: -t.correction[k].value, sigma: t.correction[k].sigma }),
            if named_offset && per_eye { "yes" } else { "-" }
        );
    }
    md += &format!(
        "| rolling-shutter readout (both cameras) | {} | {:.2} | {} | {} |\n\n",
        e(&t.readout),
        t.applied[2],
        e(&Est { value: -t.correction[2].value, sigma: t.correction[2].sigma }),
        if named_readout { "yes" } else { "no" }
    );
    if fits.len() > 1 {
        md += "Rounds (the replay run again with each estimate, `--rounds`; the table above is the last's):\n\n\
               | round | log | offset (ms) | readout (ms) | held-out improvement |\n|---|---|---|---|---|\n";
        for (k, (f, (log, _))) in fits.iter().zip(&logs).enumerate() {
            md += &format!(
                "| {k} | {} | {} | {} | {:.0} % |\n",
                log.display(),
                e(&f.offset_common),
                e(&f.readout),
                100.0 * f.improvement()
            );
        }
        md += "\n";
    }
    md += &format!(
        "**Held out** (alternate frames predict each other): on the log given, the timing terms remove {:.0} % \
         of the vertical disparity residual the static rotation leaves (RMS {:.4} -> {:.4} px).\n\n",
        100.0 * first.improvement(),
        first.heldout_rms[0],
        first.heldout_rms[1]
    );
    md += &format!(
        "**What else could explain it.** A pose error along the direction of motion whose size does not grow with \
         speed (backlash, a settling mechanism) removes {:.0} % held out{}. A mechanism that trails its encoders \
         (compliance, platform lag) gives an error proportional to the speed, exactly as an encoder offset does: it \
         appears here as offset and is corrected by it. A row-dependent error proportional to the speed has no \
         other source than the readout: lens and rectification errors do not grow with speed.\n\n",
        100.0 * first.alternative_improvement(),
        if first.alternative_improvement() >= first.improvement() - 0.02 {
            ": speed does not tell it from timing in this log (record faster or slower pursuits)"
        } else {
            ", less than the timing"
        }
    );
    md += &format!(
        "Each eye's offset is observable because the eyes both pursued (their common motion) and verged (their \
         difference); {}. The readout is one value for both cameras (the same sensor mode, rows started together).\n",
        if per_eye {
            format!("they differ by {} ms (right - left), so both are written", e(&t.offset_difference))
        } else {
            format!(
                "their difference, {} ms, is not significant, so one common value is written",
                e(&t.offset_difference)
            )
        }
    );
    if t.refine() {
        md += "\n**Refine:** the correction is large for the first-order model: re-run with these values and fit \
               the new log again.\n";
    }
    let mut console = vec![format!(
        "timing: encoder_time_offset {} ms (left {}, right {}){}, readout {} ms{}; held-out improvement {:.0} %",
        e(&t.offset_common),
        e(&t.offset[0]),
        e(&t.offset[1]),
        if named_offset { "" } else { " (not named)" },
        e(&t.readout),
        if named_readout { "" } else { " (not named)" },
        100.0 * first.improvement()
    )];
    if fits.len() > 1 {
        console.insert(0, format!("timing: {} rounds of replay with the estimate", fits.len() - 1));
    }
    if let Some(why) = &no_rounds {
        console.insert(0, format!("timing: no rounds: {why}"));
        md += &format!("\n**No rounds:** {why}.\n");
    }
    if t.refine() {
        console.push("timing: large correction: re-run with these values and fit again".into());
    }
    let mut json = t.json();
    json["heldout_improvement"] = json!(first.improvement());
    json["alternative_improvement"] = json!(first.alternative_improvement());
    json["rounds"] = fits
        .iter()
        .zip(&logs)
        .map(|(f, (log, _))| {
            json!({
                "log": log.display().to_string(),
                "encoder_time_offset_ms": f.offset_common.json(),
                "readout_ms": f.readout.json(),
                "heldout_improvement": f.improvement(),
            })
        })
        .collect();
    json["named"] = json!({ "encoder_time_offset": named_offset, "readout": named_readout, "per_eye": per_eye });
    // the edits: a failure is reported after the report is written (it does not take the report with it)
    let mut failed_writes = Vec::new();
    if let Some(p) = &a.write_config {
        match edit_toml(p, Some("motion"), &t) {
            Ok(()) => {
                console.push(format!("timing: wrote [motion] time_offset_ms, readout_ms into {}", p.display()));
                md += &format!("\nWritten into the configuration {}.\n", p.display());
            }
            Err(e) => {
                md += &format!("\nNot written into the configuration {}: {e:#}.\n", p.display());
                failed_writes.push(format!("--write-config: {e:#}"));
            }
        }
    }
    if let Some(d) = &a.write_session {
        let p = d.join("session.toml");
        match edit_toml(&p, None, &t) {
            Ok(()) => {
                console.push(format!("timing: wrote time_offset_ms, readout_ms into {}", p.display()));
                md += &format!("\nWritten into the session {}.\n", p.display());
            }
            Err(e) => {
                md += &format!("\nNot written into the session {}: {e:#}.\n", p.display());
                failed_writes.push(format!("--write-session: {e:#}"));
            }
        }
    }
    if plotted {
        md += "\n![error against eye speed](error_by_speed.png)\n";
    }
    Ok(Analysis { json, markdown: md, console, plotted, failed_writes })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn a_damaged_match_log_names_file_line_and_field() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.matches.csv");
        let head = abvs_runtime::sinks::self_check::MATCH_LOG_HEADER;
        std::fs::write(
            &p,
            format!(
                "{head}\n0,1,2,3,4,0.1,0.2,0.5,1,2,3,0.01,0.02,0,0,7\n0,1,2,3,4,0.1,0.2,oops,1,2,3,0.01,0.02,0,0,7\n"
            ),
        )
        .unwrap();
        let e = format!("{:#}", read_matches(&p).unwrap_err());
        assert!(e.contains("x.matches.csv:3") && e.contains("dy_px") && e.contains("oops"), "{e}");
        std::fs::write(&p, "seq,xl\n1,2\n").unwrap();
        let e = format!("{:#}", read_matches(&p).unwrap_err());
        assert!(e.contains("no column `row_l`"), "{e}");
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]
        /// Arbitrary bytes after a valid header: an answer or a named error, never a panic.
        #[test]
        fn the_logs_parsers_never_panic(body in proptest::collection::vec(any::<u8>(), 0..400)) {
            let dir = tempfile::tempdir().unwrap();
            let m = dir.path().join("l.matches.csv");
            let mut bytes = abvs_runtime::sinks::self_check::MATCH_LOG_HEADER.as_bytes().to_vec();
            bytes.push(b'\n');
            bytes.extend(&body);
            std::fs::write(&m, &bytes).unwrap();
            let _ = read_matches(&m);
            let f = dir.path().join("l.csv");
            let mut bytes = abvs_runtime::sinks::self_check::LOG_HEADER.as_bytes().to_vec();
            bytes.push(b'\n');
            bytes.extend(&body);
            std::fs::write(&f, &bytes).unwrap();
            if let Ok(Some(frames)) = read_frames(&f) {
                if let Ok(ms) = read_matches(&m) {
                    let _ = fit(&frames, &ms);
                }
            }
        }
    }
}
