//! The timing section of `abvs calib self-check`: the estimate of `abvs_selfcheck::rounds` (the eyes'
//! encoder-to-camera offsets and the rolling-shutter readout fitted to the log's matches, see
//! `abvs_selfcheck::timing_fit`) as report text, summary.json's `timing`, error_by_speed.png, and the
//! estimate written into a configuration or a session.
use std::path::{Path, PathBuf};

use abvs_runtime_core::session::TimeOffsetMs;
use abvs_selfcheck::rounds::{self, TimingOutcome};
use abvs_selfcheck::timing_fit::{error_by_speed, offset_setting, round2, Est, Named, TimingFit};
use abvs_selfcheck::timing_log::{read_frames_with_timing, FrameTiming};
use anyhow::{bail, Context};
use serde_json::json;

/// What the timing analysis adds to `abvs calib self-check`'s outputs.
pub struct Analysis {
    /// summary.json's `timing` (null with a `reason` when there is no estimate).
    pub json: serde_json::Value,
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

/// Estimates the timing from the log (and its match log, `abvs_selfcheck::rounds`), writes error_by_speed.png
/// and, when asked, the estimate into a configuration and a session.
pub fn analyse(a: &crate::self_check_report::SelfCheckArgs, label: &str) -> anyhow::Result<Analysis> {
    let none = |reason: String| Analysis {
        json: json!({ "reason": reason }),
        markdown: format!("\n## Timing\n\nNo estimate: {reason}.\n"),
        console: vec![format!("timing: no estimate: {reason}")],
        plotted: false,
        failed_writes: Vec::new(),
    };
    let before = match &a.before {
        Some(p) => Some(read_frames_with_timing(p)?),
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
    let analysis = rounds::analyse(&a.log, a.rounds, &a.out, &mut |line| eprintln!("{line}"))?;
    let logs = analysis.logs;
    let (fits, no_rounds) = match analysis.outcome {
        TimingOutcome::NoEstimate(reason) => {
            let mut r = none(reason);
            r.plotted = !logs.is_empty() && plot(&logs)?;
            return Ok(r);
        }
        TimingOutcome::Estimated { fits, no_rounds } => (fits, no_rounds),
    };
    let plotted = plot(&logs)?;
    let t = fits.last().expect("one fit").clone();
    let first = &fits[0];
    let Named { encoder_time_offset: named_offset, readout: named_readout, per_eye } = t.named();
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
    if let Some(why) = t.limit() {
        console.push(format!("timing: limit: {why}"));
        md += &format!("\n**Limit:** {why}.\n");
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
