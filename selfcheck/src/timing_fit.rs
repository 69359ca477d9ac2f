//! The eyes' timing fitted to a self-check log: the encoder-to-camera offset (effects.md `encoder_time_offset`)
//! per eye and the rolling-shutter readout, fitted to the vertical disparities of the matched features.
//!
//! **The evidence** (`abvs_runtime::sinks::self_check::match_timing`): the runtime reads each row's pose at
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

use abvs_runtime_core::session::TimeOffsetMs;
use nalgebra::{DMatrix, DVector};
use serde_json::{json, Value};

use crate::error::{Result, SelfCheckError};
use crate::timing_log::{steady, FrameTiming, MatchEvidence};

/// A value and its 1-sigma.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Est {
    /// The estimate.
    pub value: f64,
    /// Its standard deviation.
    pub sigma: f64,
}

impl Est {
    /// `{ value, sigma }`, rounded to 1e-4.
    pub fn json(&self) -> Value {
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
    /// Each motion segment's own fit (a run of consecutive moving frames: one pursuit), and how far they
    /// scatter beyond their sigmas ([`TimingFit::limit`] widens the sigmas above by that; they stay clustered by
    /// frame for `refine` and `named`).
    pub segments: Segments,
}

/// The timing read from each motion segment of a log on its own (with the log's frames at rest).
///
/// Consecutive frames of one pursuit see the same features, so a feature's matching error repeats from frame
/// to frame and sigmas clustered by frame understate what a log determines. Fitted per segment, the estimates
/// show it: on the shipped fixture at 640x480 with the true timing applied (docs/self-check.md) the two
/// pursuits read the left offset 3.37 +- 0.35 and 2.12 +- 0.14 ms. The scatter between segments (the Birge
/// ratio, sqrt(chi^2 / (n - 1)), at least 1) scales the fit's sigmas in [`TimingFit::limit`].
#[derive(Debug, Clone, PartialEq)]
pub struct Segments {
    /// Per segment: its first and last frame, and its corrections (offset left, right, readout; ms).
    pub fits: Vec<(u64, u64, [Est; 3])>,
    /// Birge ratio of the segments' offsets (the larger eye's) and readout; 1 with fewer than two segments.
    pub ratio: [f64; 2],
}

/// Why a log cannot give the timing to the accuracy the rounds ask of it (0.3 ms of offset, 2 ms of
/// readout): reported instead of a value that would look more certain than it is.
#[derive(Debug, Clone, PartialEq)]
pub enum TimingLimit {
    /// The log determines the offset or the readout only to these 2-sigma bounds (ms), larger than asked;
    /// `ratio` says how much of that is the scatter between its motion segments.
    Undetermined {
        /// 2 sigma of the offsets (the larger eye's) and of the readout (ms), sigmas holding the segments' scatter.
        two_sigma_ms: [f64; 2],
        /// Motion segments fitted on their own.
        segments: usize,
        /// Their Birge ratio [offset, readout].
        ratio: [f64; 2],
    },
}

impl std::fmt::Display for TimingLimit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            TimingLimit::Undetermined { two_sigma_ms, segments, ratio } => {
                write!(
                    f,
                    "this log determines the offset to +-{:.2} ms and the readout to +-{:.2} ms (2 sigma; asked: 0.3 \
                     and 2 ms)",
                    two_sigma_ms[0], two_sigma_ms[1]
                )?;
                if *segments >= 2 {
                    write!(
                        f,
                        "; its {segments} motion segments read the timing {:.1} / {:.1} times further apart than \
                         their own sigmas (offset / readout)",
                        ratio[0], ratio[1]
                    )?;
                } else {
                    write!(
                        f,
                        "; it has {segments} motion segment of 3 or more steady frames, so the scatter between \
                         pursuits is not measured"
                    )?;
                }
                write!(f, ": record more pursuits, each with vergence, and fit again")
            }
        }
    }
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
    /// Why this log cannot give the timing to the accuracy the rounds ask, if it cannot.
    pub fn limit(&self) -> Option<TimingLimit> {
        let off = 2.0 * self.correction[0].sigma.max(self.correction[1].sigma) * self.segments.ratio[0];
        let ro = 2.0 * self.correction[2].sigma * self.segments.ratio[1];
        (off > 0.3 || ro > 2.0).then_some(TimingLimit::Undetermined {
            two_sigma_ms: [off, ro],
            segments: self.segments.fits.len(),
            ratio: self.segments.ratio,
        })
    }
    /// Which effects the estimate names: each beyond three sigmas and the smallest size that is not the
    /// fit's own bias ([`MIN_OFFSET_MS`], [`MIN_READOUT_MS`]).
    pub fn named(&self) -> Named {
        Named {
            encoder_time_offset: self.offset_common.significant(3.0) && self.offset_common.value.abs() >= MIN_OFFSET_MS,
            readout: self.readout.significant(3.0) && self.readout.value.abs() >= MIN_READOUT_MS,
            per_eye: self.offset_difference.significant(3.0) && self.offset_difference.value.abs() >= MIN_OFFSET_MS,
        }
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
            "segments": self.segments.fits.iter().map(|(a, b, c)| json!({
                "seqs": [a, b], "offset_left": c[0].json(), "offset_right": c[1].json(), "readout": c[2].json(),
            })).collect::<Vec<_>>(),
            "segments_birge_ratio": { "offset": self.segments.ratio[0], "readout": self.segments.ratio[1] },
            "limit": self.limit().map(|l| l.to_string()),
        })
    }
}

/// The effects an estimate names (summary.json's `timing.named`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Named {
    /// An encoder-to-camera offset (both eyes' mean).
    pub encoder_time_offset: bool,
    /// A rolling-shutter readout.
    pub readout: bool,
    /// The eyes' offsets differ: one per eye is written.
    pub per_eye: bool,
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

/// The corrections a fit gives (ms): left, right, their mean, readout, right minus left. `a`: the middle row's
/// distance below the row the stamps fix. `eps_k(rho) = tau_k + dR (rho - 1/2) = dT_k + dR (rho - anchor)`, so
/// `dT_k = tau_k - dR (1/2 - anchor)`.
fn corrections(f: &Fitted, a: f64) -> [Est; 5] {
    let (b, c) = (&f.beta, &f.cov);
    let lin = |coef: &[(usize, f64)]| -> Est {
        let value = coef.iter().map(|(i, a)| a * b[*i]).sum();
        let var: f64 = coef.iter().flat_map(|(i, a)| coef.iter().map(move |(j, bb)| a * bb * c[(*i, *j)])).sum();
        Est { value, sigma: var.max(0.0).sqrt() }
    };
    [
        lin(&[(3, 1.0), (5, -a)]),
        lin(&[(4, 1.0), (5, -a)]),
        lin(&[(3, 0.5), (4, 0.5), (5, -a)]),
        lin(&[(5, 1.0)]),
        lin(&[(4, 1.0), (3, -1.0)]),
    ]
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

/// Fits the timing to a log's frames and matches. `None` when too few steady frames with matches moved.
pub fn fit(frames: &[FrameTiming], matches: &[MatchEvidence]) -> Result<Option<TimingFit>> {
    let by_seq: BTreeMap<u64, &FrameTiming> = frames.iter().map(|f| (f.seq, f)).collect();
    let first = match frames.first() {
        Some(f) => *f,
        None => return Ok(None),
    };
    if let Some(f) = frames
        .iter()
        .find(|f| f.readout_ms != first.readout_ms || f.offset_ms != first.offset_ms || f.anchor != first.anchor)
    {
        return Err(SelfCheckError::TimingChanged {
            seq: f.seq,
            readout_ms: f.readout_ms,
            offset_ms: f.offset_ms,
            first_readout_ms: first.readout_ms,
            first_offset_ms: first.offset_ms,
        });
    }
    let mut logged = std::collections::BTreeSet::new();
    let mut used: Vec<(&MatchEvidence, &FrameTiming)> = Vec::new();
    for m in matches {
        let Some(f) = by_seq.get(&m.seq) else {
            return Err(SelfCheckError::MatchWithoutFrame { seq: m.seq });
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

    let a = 0.5 - first.anchor;
    let [d_left, d_right, d_common, d_readout, diff] = corrections(&full, a);
    // each motion segment on its own, with the frames at rest (they fix the static rotation)
    let moving = |s: u64| by_seq[&s].speed[0].max(by_seq[&s].speed[1]) >= 5.0;
    let mut runs: Vec<Vec<u64>> = Vec::new();
    for &s in seqs.iter().filter(|s| moving(**s)) {
        match runs.last_mut() {
            Some(r) if s - r[r.len() - 1] <= 2 => r.push(s),
            _ => runs.push(vec![s]),
        }
    }
    let mut seg_fits = Vec::new();
    for r in runs.iter().filter(|r| r.len() >= 3) {
        let (lo, hi) = (r[0], r[r.len() - 1]);
        if let Some(f) = irls(&rows(Terms::Timing, &|s| !moving(s) || (lo..=hi).contains(&s))) {
            let [l, rr, _, ro, _] = corrections(&f, a);
            seg_fits.push((lo, hi, [l, rr, ro]));
        }
    }
    let birge = |k: usize| -> f64 {
        let n = seg_fits.len();
        let ok = seg_fits.iter().all(|(_, _, c)| c[k].sigma > 0.0 && c[k].sigma.is_finite());
        if n < 2 || !ok {
            return 1.0;
        }
        let w: f64 = seg_fits.iter().map(|(_, _, c)| c[k].sigma.powi(-2)).sum();
        let m: f64 = seg_fits.iter().map(|(_, _, c)| c[k].value * c[k].sigma.powi(-2)).sum::<f64>() / w;
        let chi2: f64 = seg_fits.iter().map(|(_, _, c)| ((c[k].value - m) / c[k].sigma).powi(2)).sum();
        (chi2 / (n - 1) as f64).sqrt().max(1.0)
    };
    let ratio = [birge(0).max(birge(1)), birge(2)];
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
        segments: Segments { fits: seg_fits, ratio },
    }))
}

/// Smallest offset (ms) and readout (ms) named as an effect: below them the fit's first-order bias (a few
/// tenths of a millisecond of offset, about a millisecond of readout on rendered sessions with the true
/// timing applied) could name an effect that is not there.
pub const MIN_OFFSET_MS: f64 = 0.2;
/// Smallest readout named as an effect (ms).
pub const MIN_READOUT_MS: f64 = 2.0;

/// Rounded to 0.01 (what is written into a configuration).
pub fn round2(x: f64) -> f64 {
    (x * 100.0).round() / 100.0
}

/// The timing setting of an estimate: one offset, or one per eye when they differ beyond three sigmas.
pub fn offset_setting(t: &TimingFit) -> TimeOffsetMs {
    if t.offset_difference.significant(3.0) && t.offset_difference.value.abs() >= MIN_OFFSET_MS {
        TimeOffsetMs::PerEye([round2(t.offset[0].value), round2(t.offset[1].value)])
    } else {
        TimeOffsetMs::Both(round2(t.offset_common.value))
    }
}

/// Median |rotation error| (deg) of the frames in each speed band: the curve of error_by_speed.png.
pub fn error_by_speed(frames: &[FrameTiming]) -> Vec<(f64, f64)> {
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

#[cfg(test)]
mod fuzz {
    use crate::timing_log::{read_frames, read_matches};
    use abvs_runtime::sinks::self_check::log_record::{FrameRecord, LogRecord, MatchRecord};
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]
        /// Arbitrary bytes after a valid header: an answer or a named error from the parsers and the fit, never
        /// a panic.
        #[test]
        fn the_logs_parsers_and_the_fit_never_panic(body in proptest::collection::vec(any::<u8>(), 0..400)) {
            let dir = tempfile::tempdir().unwrap();
            let m = dir.path().join("l.matches.csv");
            let mut bytes = MatchRecord::header().into_bytes();
            bytes.push(b'\n');
            bytes.extend(&body);
            std::fs::write(&m, &bytes).unwrap();
            let _ = read_matches(&m);
            let f = dir.path().join("l.csv");
            let mut bytes = FrameRecord::header().into_bytes();
            bytes.push(b'\n');
            bytes.extend(&body);
            std::fs::write(&f, &bytes).unwrap();
            if let Ok(Some(frames)) = read_frames(&f) {
                if let Ok(ms) = read_matches(&m) {
                    let _ = super::fit(&frames, &ms);
                }
            }
        }
    }
}

#[cfg(test)]
mod segments {
    use super::*;

    /// A log of `segs` pursuits (8 moving frames each, 40 matches a frame), each after 8 frames at rest, with the
    /// vertical disparities of the first-order model: each segment's own time errors (left, right offset; ms)
    /// at a 30 ms readout, plus 0.05 px of matching noise.
    fn log(segs: &[[f64; 2]]) -> (Vec<FrameTiming>, Vec<MatchEvidence>) {
        let mut state = 12345u64;
        let mut rnd = move || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        };
        let (mut frames, mut matches, mut seq) = (Vec::new(), Vec::new(), 0u64);
        let frame = |seq: u64, speed: f64| FrameTiming {
            seq,
            speed: [speed, speed],
            accel: [0.0, 0.0],
            readout_ms: 30.0,
            anchor: 0.0,
            offset_ms: [3.0, 3.0],
            error_deg: 0.0,
            row_bands: Some(8),
            run_id: None,
        };
        for (k, eps) in segs.iter().flat_map(|e| [None, Some(e)]).enumerate() {
            for i in 0..8 {
                let moving = eps.is_some();
                frames.push(frame(seq, if moving { 40.0 + 20.0 * (i as f64 / 7.0) } else { 0.0 }));
                for _ in 0..40 {
                    let row = [0.5 + 0.5 * rnd(), 0.5 + 0.5 * rnd()];
                    let j = [400.0 + 50.0 * rnd(), 300.0 * rnd(), 300.0 * rnd()];
                    let s =
                        if moving { [0.3 * rnd() + 0.1 * k as f64, 0.3 * rnd() - 0.1 * k as f64] } else { [0.0; 2] };
                    let e = eps.copied().unwrap_or([0.0; 2]);
                    let dy = (0..2).map(|q| s[q] * e[q]).sum::<f64>() + 0.05 * rnd();
                    matches.push(MatchEvidence { seq, row, dy, j, s, u: [0.0; 2] });
                }
                seq += 1;
            }
        }
        (frames, matches)
    }

    #[test]
    fn pursuits_that_agree_keep_the_sigmas_and_name_no_limit() {
        let (f, m) = log(&[[0.4, -0.2], [0.4, -0.2]]);
        let t = fit(&f, &m).unwrap().unwrap();
        assert_eq!(t.segments.fits.len(), 2, "{:?}", t.segments);
        assert!(t.segments.ratio[0] < 2.0, "{:?}", t.segments);
        assert!((t.correction[0].value - 0.4).abs() < 0.1 && (t.correction[1].value + 0.2).abs() < 0.1, "{t:?}");
        assert_eq!(t.limit(), None, "{t:?}");
    }

    #[test]
    fn pursuits_that_disagree_widen_the_sigmas_and_say_why() {
        let (f, m) = log(&[[1.5, 1.5], [-1.5, -1.5]]);
        let t = fit(&f, &m).unwrap().unwrap();
        assert!(t.segments.ratio[0] > 3.0, "{:?}", t.segments);
        let why = t.limit().expect("a limit").to_string();
        assert!(why.contains("its 2 motion segments"), "{why}");
        // the bound it gives holds the two pursuits' disagreement
        let Some(TimingLimit::Undetermined { two_sigma_ms, .. }) = t.limit() else { unreachable!() };
        assert!(two_sigma_ms[0] > 1.0, "{two_sigma_ms:?}");
    }
}
