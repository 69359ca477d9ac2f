//! `abvs calib self-check --log FILE --out DIR`: the offline side of the runtime's self-check. Reads a
//! `--self-check-log` CSV (per checked frame: both eyes' link angles and the relative rotation error measured
//! from the images) and reports where in the workspace the error is and which eye it follows:
//!
//! - each frame's gaze per eye (Fick angles of the nominal FK at its link angles),
//! - the error's constant part (the home stereo extrinsic, or an error common to all poses) and what varies,
//! - how much of the varying part a smooth function of each eye's gaze explains (least squares on
//!   1, yaw, pitch, torsion and their squares, per component; held out by leave-one-fixation-out, so a
//!   model cannot explain a frame by itself), for the left eye, the right eye and both,
//! - `error_by_frame.png` (the three components per frame), `error_over_gaze.png` (mean |error| over each
//!   eye's yaw x pitch, side by side), `report.md` and `summary.json`.
//!
//! An eye is named when its gaze explains most of the varying error and leaves at most half of what the other
//! eye's gaze leaves unexplained. When both eyes look at the same targets their gazes move together (the
//! fixture's correlate at 0.99) and only vergence and the nonlinear terms tell them apart; when they do not,
//! the report says so (with the correlation of the eyes' gazes) instead of naming an eye.
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use abvs_eye::{Fick, UnitModel};
use abvs_plot::{side_by_side, xy_plot, Reduce, Series, SeriesStyle, XyPlot};
use anyhow::{bail, Context};
use clap::Args;
use nalgebra::{DMatrix, DVector};
use serde_json::json;

#[derive(Args)]
pub struct SelfCheckArgs {
    /// A self-check log (`abvs run --self-check-log FILE`).
    #[arg(long)]
    pub log: PathBuf,
    /// Output directory (report.md, summary.json, PNGs).
    #[arg(long)]
    pub out: PathBuf,
    /// Heatmap cell size (deg of gaze, 0.1 to 30).
    #[arg(long, default_value_t = 2.0, value_parser = crate::args::finite_in(0.1, 30.0))]
    pub cell_deg: f64,
    /// Write the estimated timing into this deployment configuration (`[motion] time_offset_ms`,
    /// `readout_ms`; the file's comments are kept) so that the next `abvs run --config` uses it.
    #[arg(long, value_name = "FILE")]
    pub write_config: Option<PathBuf>,
    /// Write the estimated timing into this session's session.toml (`time_offset_ms`, `readout_ms`) so that
    /// the next replay of it uses it.
    #[arg(long, value_name = "DIR")]
    pub write_session: Option<PathBuf>,
    /// A log of an earlier run (e.g. before the timing was corrected): drawn beside this one in
    /// error_by_speed.png.
    #[arg(long, value_name = "LOG")]
    pub before: Option<PathBuf>,
    /// When the log is of a replay (its `.run.toml` names a session that is still there): re-run the replay
    /// with the timing estimate and fit again, up to this many rounds while the correction is large (the
    /// model is first order); 0 fits the log alone. Each round's log lands in the output directory.
    #[arg(long, default_value_t = 3, value_parser = crate::args::count(0u32, 10))]
    pub rounds: u32,
}

impl SelfCheckArgs {
    /// The files it will write or edit, before any work (`main`'s check).
    pub fn check(&self) -> anyhow::Result<()> {
        crate::self_check_timing::check_outputs(self)
    }
}

/// One logged frame: its gaze per eye (yaw, pitch, torsion; deg) and the measured error (deg).
struct Row {
    seq: u64,
    theta: [[f64; 3]; 2],
    gaze: [[f64; 3]; 2],
    err: [f64; 3],
}

fn read_log(path: &Path) -> anyhow::Result<Vec<Row>> {
    let mut rd = csv::Reader::from_path(path).with_context(|| format!("reading {}", path.display()))?;
    let head = rd.headers()?.clone();
    let col = |name: &str| {
        head.iter().position(|h| h == name).with_context(|| format!("{}: no column `{name}`", path.display()))
    };
    let names = ["l1_deg", "l2_deg", "l3_deg", "r1_deg", "r2_deg", "r3_deg", "rot_x_deg", "rot_y_deg", "rot_z_deg"];
    let idx: Vec<usize> = names.iter().map(|n| col(n)).collect::<anyhow::Result<_>>()?;
    let seq_col = col("seq")?;
    let fk = UnitModel::nominal().compile()?;
    let (mut sl, mut sr) = (fk.stream(), fk.stream());
    let mut rows = Vec::new();
    for (i, rec) in rd.records().enumerate() {
        let rec = rec.with_context(|| format!("{}: record {}", path.display(), i + 2))?;
        let num = |k: usize| -> anyhow::Result<f64> {
            let s = rec.get(k).unwrap_or("").trim();
            if s.is_empty() {
                return Ok(f64::NAN);
            }
            s.parse().with_context(|| format!("{}:{}: `{s}` is not a number", path.display(), i + 2))
        };
        let v: Vec<f64> = idx.iter().map(|&k| num(k)).collect::<anyhow::Result<_>>()?;
        let seq = num(seq_col)? as u64;
        let theta = [[v[0], v[1], v[2]], [v[3], v[4], v[5]]];
        let (pl, pr) = (fk.next(&mut sl, &theta[0], [0.0, 1.0, 0.0])?, fk.next(&mut sr, &theta[1], [0.0, 1.0, 0.0])?);
        let fick = |r: &nalgebra::Matrix3<f64>| {
            let f = Fick::from_matrix(r);
            [f.gamma.to_degrees(), f.alpha.to_degrees(), f.beta.to_degrees()]
        };
        let err = [v[6], v[7], v[8]];
        if err.iter().all(|x| x.is_finite()) {
            rows.push(Row { seq, theta, gaze: [fick(&pl.r), fick(&pr.r)], err });
        }
    }
    Ok(rows)
}

/// Smooth features of a gaze: 1, yaw, pitch, torsion, yaw^2, pitch^2, yaw pitch.
fn features(g: &[f64; 3]) -> Vec<f64> {
    let (y, p, t) = (g[0] / 10.0, g[1] / 10.0, g[2] / 10.0);
    vec![y, p, t, y * y, p * p, y * p]
}

/// Held-out fraction of the error's variance (about its mean) explained by `feat` of each frame: least
/// squares on 1 + the features, each fixation (a run of frames with the same link angles) predicted by a fit
/// to the others. Ridge-regularised a little, for fixations that leave a feature undetermined.
fn explained(rows: &[Row], feat: &dyn Fn(&Row) -> Vec<f64>, groups: &[usize]) -> f64 {
    let n = rows.len();
    let x: Vec<Vec<f64>> = rows.iter().map(|r| std::iter::once(1.0).chain(feat(r)).collect()).collect();
    let k = x[0].len();
    let mean: Vec<f64> = (0..3).map(|c| rows.iter().map(|r| r.err[c]).sum::<f64>() / n as f64).collect();
    let total: f64 = rows.iter().map(|r| (0..3).map(|c| (r.err[c] - mean[c]).powi(2)).sum::<f64>()).sum();
    if total <= 0.0 {
        return 0.0;
    }
    let ngroups = groups.iter().max().map_or(0, |g| g + 1);
    let mut resid = 0.0;
    for g in 0..ngroups {
        let train: Vec<usize> = (0..n).filter(|&i| groups[i] != g).collect();
        if train.len() < k {
            return f64::NAN;
        }
        let a = DMatrix::from_fn(train.len(), k, |i, j| x[train[i]][j]);
        let mut ata = a.transpose() * &a;
        for j in 1..k {
            ata[(j, j)] += 1e-3 * train.len() as f64;
        }
        let Some(inv) = ata.try_inverse() else { return f64::NAN };
        for c in 0..3 {
            let b = DVector::from_iterator(train.len(), train.iter().map(|&i| rows[i].err[c]));
            let coef = &inv * (a.transpose() * b);
            for i in (0..n).filter(|&i| groups[i] == g) {
                let pred: f64 = (0..k).map(|j| coef[j] * x[i][j]).sum();
                resid += (rows[i].err[c] - pred).powi(2);
            }
        }
    }
    1.0 - resid / total
}

/// Fixations: runs of frames whose link angles stay within 0.05 deg of the run's first frame.
fn fixations(rows: &[Row]) -> Vec<usize> {
    let mut g = Vec::with_capacity(rows.len());
    let mut id = 0;
    let mut start = 0;
    for (i, r) in rows.iter().enumerate() {
        let same = i > 0 && (0..2).all(|e| (0..3).all(|k| (r.theta[e][k] - rows[start].theta[e][k]).abs() < 0.05));
        if i > 0 && !same {
            id += 1;
            start = i;
        }
        g.push(id);
    }
    g
}

fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma) * (x - ma);
        sbb += (y - mb) * (y - mb);
    }
    if saa > 0.0 && sbb > 0.0 {
        sab / (saa * sbb).sqrt()
    } else {
        f64::NAN
    }
}

/// The verdict from the error's varying and constant parts (deg) and the fractions of the varying part each
/// eye's gaze explains (held out). A verdict names what the fractions support: an eye when its gaze explains
/// most of the error (over half) and leaves at most half of what the other's leaves unexplained; "either
/// eye" only when both explain most of it. A fraction at or below one half, a negative one included (the
/// held-out fit predicts worse than the mean), supports nothing: the verdict then says it cannot tell.
fn verdict(varying: f64, constant: f64, r2: [f64; 2], gaze_corr: [f64; 2]) -> String {
    let [r2_left, r2_right] = r2;
    let follows = |a: f64, b: f64| a > 0.5 && 1.0 - a <= 0.5 * (1.0 - b.max(0.0));
    if varying < 0.02 && constant < 0.02 {
        "no significant error: both eyes' models and the home extrinsic agree with the images".to_string()
    } else if varying < 0.5 * constant {
        "mostly constant: the home stereo extrinsic (stereo.yaml), or an error both eyes share at every pose".into()
    } else if !(r2_left.is_finite() && r2_right.is_finite()) {
        "varies with the pose, but the log has too few fixations to tell which eye it follows".into()
    } else if follows(r2_right, r2_left) {
        format!(
            "the right eye's model (its gaze explains {:.0} % of the varying error, the left's {:.0} %)",
            100.0 * r2_right,
            100.0 * r2_left
        )
    } else if follows(r2_left, r2_right) {
        format!(
            "the left eye's model (its gaze explains {:.0} % of the varying error, the right's {:.0} %)",
            100.0 * r2_left,
            100.0 * r2_right
        )
    } else if r2_left > 0.5 && r2_right > 0.5 {
        format!(
            "varies with the pose, but the eyes' gazes moved together (correlation yaw {:.2}, pitch {:.2}): either \
             eye's model explains it (left {:.0} %, right {:.0} %); a log with the eyes verging independently tells \
             them apart",
            gaze_corr[0],
            gaze_corr[1],
            100.0 * r2_left,
            100.0 * r2_right
        )
    } else {
        format!(
            "varies with the pose, but cannot tell which eye it follows: neither eye's gaze explains most of it \
             (left {:.0} %, right {:.0} %, held out; below 0 the gaze predicts it worse than its mean does)",
            100.0 * r2_left,
            100.0 * r2_right
        )
    }
}

pub fn run(a: SelfCheckArgs) -> anyhow::Result<ExitCode> {
    let rows = read_log(&a.log)?;
    if rows.len() < 3 {
        bail!("{}: {} frames with a rotation error; at least 3 are needed", a.log.display(), rows.len());
    }
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let n = rows.len() as f64;
    let mean: Vec<f64> = (0..3).map(|c| rows.iter().map(|r| r.err[c]).sum::<f64>() / n).collect();
    let spread: Vec<f64> =
        (0..3).map(|c| (rows.iter().map(|r| (r.err[c] - mean[c]).powi(2)).sum::<f64>() / n).sqrt()).collect();
    let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
    let mut mags: Vec<f64> = rows.iter().map(|r| norm(&r.err)).collect();
    mags.sort_by(f64::total_cmp);
    let q = |p: f64| mags[((mags.len() - 1) as f64 * p).round() as usize];
    let groups = fixations(&rows);
    let nfix = groups.last().map_or(0, |g| g + 1);
    let (r2_left, r2_right, r2_both) = if nfix >= 3 {
        (
            explained(&rows, &|r| features(&r.gaze[0]), &groups),
            explained(&rows, &|r| features(&r.gaze[1]), &groups),
            explained(&rows, &|r| [features(&r.gaze[0]), features(&r.gaze[1])].concat(), &groups),
        )
    } else {
        (f64::NAN, f64::NAN, f64::NAN)
    };
    let yaw = |e: usize| rows.iter().map(|r| r.gaze[e][0]).collect::<Vec<f64>>();
    let pitch = |e: usize| rows.iter().map(|r| r.gaze[e][1]).collect::<Vec<f64>>();
    let gaze_corr = [correlation(&yaw(0), &yaw(1)), correlation(&pitch(0), &pitch(1))];
    // the worst fixation: where in the workspace the error is largest
    let mut by_fix: BTreeMap<usize, (f64, usize, usize)> = BTreeMap::new();
    for (i, (r, g)) in rows.iter().zip(&groups).enumerate() {
        let e = by_fix.entry(*g).or_insert((0.0, 0, i));
        e.0 += norm(&r.err);
        e.1 += 1;
    }
    let (_, &(sum, cnt, first)) =
        by_fix.iter().max_by(|a, b| (a.1 .0 / a.1 .1 as f64).total_cmp(&(b.1 .0 / b.1 .1 as f64))).expect("rows");
    let worst = &rows[first];
    let verdict = verdict(norm(&spread), norm(&mean), [r2_left, r2_right], gaze_corr);

    // figures
    let series = |c: usize, label: &'static str| Series {
        label,
        points: rows.iter().map(|r| (r.seq as f64, r.err[c])).collect(),
        style: SeriesStyle::LinePoints,
    };
    xy_plot(
        &a.out.join("error_by_frame.png"),
        &XyPlot {
            title: "relative rotation error per checked frame (left home frame)",
            x_label: "frame (seq)",
            y_label: "rotation error, deg",
            series: vec![series(0, "x"), series(1, "y"), series(2, "z")],
            log_y: false,
        },
    )?;
    let map = |e: usize, title: &'static str| {
        let pts: Vec<(f64, f64, f64)> = rows.iter().map(|r| (r.gaze[e][1], r.gaze[e][0], norm(&r.err))).collect();
        crate::plot::workspace_map(title, "mean |rotation error|, deg", &pts, a.cell_deg, Reduce::Mean)
    };
    side_by_side(
        &a.out.join("error_over_gaze.png"),
        &map(0, "over the left eye's gaze"),
        &map(1, "over the right eye's gaze"),
    )?;

    let summary = json!({
        "log": a.log.display().to_string(),
        "frames": rows.len(),
        "fixations": nfix,
        "error_mean_deg": mean,
        "error_spread_deg": spread,
        "error_norm_deg": { "p50": q(0.5), "p95": q(0.95), "max": q(1.0) },
        "explained_by_gaze": { "left": r2_left, "right": r2_right, "both": r2_both },
        "gaze_correlation": { "yaw": gaze_corr[0], "pitch": gaze_corr[1] },
        "worst_fixation": {
            "from_seq": worst.seq,
            "frames": cnt,
            "mean_error_norm_deg": sum / cnt as f64,
            "left_gaze_deg": worst.gaze[0],
            "right_gaze_deg": worst.gaze[1],
        },
        "verdict": verdict,
    });
    let timing = crate::self_check_timing::analyse(&a, &rows_speed_plot_label(&a))?;
    let mut summary = summary;
    summary["timing"] = timing.json;
    std::fs::write(a.out.join("summary.json"), serde_json::to_string_pretty(&summary)? + "\n")?;
    let f = |x: f64| if x.is_finite() { format!("{:.0} %", 100.0 * x) } else { "-".into() };
    let g = |v: &[f64; 3]| format!("yaw {:.1}, pitch {:.1}, torsion {:.1}", v[0], v[1], v[2]);
    let report = format!(
        "# Self-check log: {}\n\n{} checked frames in {} fixations.\n\n\
         **Verdict:** {verdict}.\n\n\
         | | x | y | z |\n|---|---|---|---|\n\
         | mean error (deg) | {:.4} | {:.4} | {:.4} |\n| spread about the mean (deg) | {:.4} | {:.4} | {:.4} |\n\n\
         |error| per frame: p50 {:.4}, p95 {:.4}, max {:.4} deg. Largest at the fixation from frame {} ({} frames, \
         mean {:.4} deg): left eye {}, right eye {} (deg).\n\n\
         Varying error explained by each eye's gaze (held out by fixation): left {}, right {}, both {}; \
         correlation of the eyes' gazes: yaw {:.2}, pitch {:.2}.\n\n\
         ![error per frame](error_by_frame.png)\n\n![error over gaze](error_over_gaze.png)\n",
        a.log.display(),
        rows.len(),
        nfix,
        mean[0],
        mean[1],
        mean[2],
        spread[0],
        spread[1],
        spread[2],
        q(0.5),
        q(0.95),
        q(1.0),
        worst.seq,
        cnt,
        sum / cnt as f64,
        g(&worst.gaze[0]),
        g(&worst.gaze[1]),
        f(r2_left),
        f(r2_right),
        f(r2_both),
        gaze_corr[0],
        gaze_corr[1]
    );
    std::fs::write(a.out.join("report.md"), report + &timing.markdown)?;
    println!("{} frames, {} fixations: {verdict}", rows.len(), nfix);
    for line in &timing.console {
        println!("{line}");
    }
    println!(
        "wrote {}/report.md, summary.json, error_by_frame.png, error_over_gaze.png{}",
        a.out.display(),
        if timing.plotted { ", error_by_speed.png" } else { "" }
    );
    if !timing.failed_writes.is_empty() {
        bail!("{} (the report and summary.json were written to {})", timing.failed_writes.join("; "), a.out.display());
    }
    Ok(ExitCode::SUCCESS)
}

/// The legend of this log's curve in error_by_speed.png.
fn rows_speed_plot_label(a: &SelfCheckArgs) -> String {
    if a.before.is_some() {
        "this run".into()
    } else {
        "self-check".into()
    }
}

#[cfg(test)]
mod tests {
    use super::verdict;

    #[test]
    fn a_negative_or_small_explained_fraction_supports_no_verdict() {
        let corr = [0.99, 0.98];
        // the fractions the issue saw on the fixture and on rendered sessions: no eye is named, no "explains it"
        for r2 in [[-0.62, -0.72], [-0.11, -0.09], [-0.18, -0.21], [0.3, -0.5], [0.45, 0.4]] {
            let v = verdict(0.1, 0.01, r2, corr);
            assert!(v.contains("cannot tell"), "{r2:?}: {v}");
            assert!(!v.contains("explains it") && !v.contains("eye's model ("), "{r2:?}: {v}");
        }
        // fractions that support a verdict still give it
        assert!(verdict(0.1, 0.01, [0.9, 0.2], corr).starts_with("the left eye's model"));
        assert!(verdict(0.1, 0.01, [-0.3, 0.8], corr).starts_with("the right eye's model"));
        assert!(verdict(0.1, 0.01, [0.8, 0.75], corr).contains("either eye's model explains it"));
        assert!(verdict(0.01, 0.01, [-0.6, -0.7], corr).starts_with("no significant error"));
    }
}
