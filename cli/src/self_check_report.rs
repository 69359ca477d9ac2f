//! `abvs calib self-check --log FILE --out DIR`: the offline side of the runtime's self-check. Reads a
//! `--self-check-log` CSV and reports where in the workspace the error is and which eye it follows
//! (`abvs_selfcheck::attribution`), and the eyes' timing (`abvs_selfcheck::rounds`, the section of
//! `self_check_timing`): `error_by_frame.png` (the three components per frame), `error_over_gaze.png` (mean
//! |error| over each eye's yaw x pitch, side by side), `report.md` and `summary.json`.
use std::{path::PathBuf, process::ExitCode};

use abvs_plot::{side_by_side, xy_plot, Reduce, Series, SeriesStyle, XyPlot};
use abvs_selfcheck::attribution::{attribute, Attribution};
use anyhow::{bail, Context};
use clap::Args;
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
    /// with the timing estimate and fit again, up to this many rounds (0 to 10) while the correction is large
    /// (the model is first order); 0 fits the log alone. Each round's log lands in the output directory.
    #[arg(long, default_value_t = 3, value_parser = crate::args::count(0u32, 10))]
    pub rounds: u32,
}

impl SelfCheckArgs {
    /// The files it will write or edit, before any work (`main`'s check).
    pub fn check(&self) -> anyhow::Result<()> {
        crate::self_check_timing::check_outputs(self)
    }
}

pub fn run(a: SelfCheckArgs) -> anyhow::Result<ExitCode> {
    let Attribution {
        rows,
        fixations: nfix,
        mean_deg: mean,
        spread_deg: spread,
        noise_deg: noise,
        norm_deg: [p50, p95, max],
        explained: [r2_left, r2_right, r2_both],
        eye_test,
        gaze_correlation: gaze_corr,
        worst,
        verdict,
    } = attribute(&a.log)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
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
        "error_noise_deg": noise,
        "error_norm_deg": { "p50": p50, "p95": p95, "max": max },
        "explained_by_fk": { "left": r2_left, "right": r2_right, "both": r2_both },
        "eye_test": eye_test.map(|t| t.json()),
        "gaze_correlation": { "yaw": gaze_corr[0], "pitch": gaze_corr[1] },
        "worst_fixation": {
            "from_seq": worst.from_seq,
            "frames": worst.frames,
            "mean_error_norm_deg": worst.mean_error_norm_deg,
            "left_gaze_deg": worst.gaze_deg[0],
            "right_gaze_deg": worst.gaze_deg[1],
        },
        "verdict": verdict.to_string(),
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
         Varying error explained by each eye's FK model (held out by fixation): left {}, right {}, both {}; \
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
        p50,
        p95,
        max,
        worst.from_seq,
        worst.frames,
        worst.mean_error_norm_deg,
        g(&worst.gaze_deg[0]),
        g(&worst.gaze_deg[1]),
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
