//! `abvs calib explain`: the discrepancy workflow on a measured dataset.
use abvs_calib::explain::{explain, report_markdown, summary_json, ExplainOptions};
use abvs_eye::dataset::Dataset;
use abvs_eye::UnitModel;
use anyhow::Context;
use clap::Args;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

#[derive(Args)]
pub struct ExplainArgs {
    /// Measured dataset CSV (docs/spec/dataset.md).
    #[arg(long)]
    data: PathBuf,
    /// Starting unit model (default: the nominal unit with the geometric effects every real
    /// unit has, fitted first as the known model).
    #[arg(long)]
    model: Option<PathBuf>,
    /// Report directory (report.md, PNGs, unit.toml, summary.json).
    #[arg(long)]
    out: PathBuf,
    /// Seed of the cross-validation folds.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Cross-validation folds (2 to 20).
    #[arg(long, default_value_t = 3, value_parser = crate::args::count(2usize, 20))]
    folds: usize,
}

pub fn run(a: ExplainArgs) -> anyhow::Result<ExitCode> {
    let data = Dataset::read(&a.data)?;
    let start = match &a.model {
        Some(p) => UnitModel::load(p)?,
        None => UnitModel::nominal(),
    };
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let t0 = Instant::now();
    let opts = ExplainOptions { seed: a.seed, folds: a.folds, ..Default::default() };
    let bar = indicatif::ProgressBar::new_spinner();
    let r = explain(&start, &data, &opts, &mut |m| {
        bar.set_message(format!("[{:>5.1} s] {m}", t0.elapsed().as_secs_f64()));
        bar.tick();
    })?;
    bar.finish_and_clear();
    let plots = crate::explain_plots::write(&a.out, &data, &r)?;
    let name = a.data.display().to_string();
    std::fs::write(a.out.join("report.md"), report_markdown(&r, &name, &plots))?;
    std::fs::write(a.out.join("summary.json"), serde_json::to_string_pretty(&summary_json(&r))?)?;
    let mut unit = r.unit.clone();
    unit.name = format!("explained from {}", a.data.display());
    unit.save(&a.out.join("unit.toml"))?;
    for n in &r.start_notes {
        println!("start: {n}");
    }
    println!(
        "noise floor {:.4} deg / {:.4} mm; held-out {:.4} deg / {:.4} mm at start",
        r.noise_floor_rot_deg, r.noise_floor_trans_mm, r.initial_rms.0, r.initial_rms.1
    );
    for s in &r.steps {
        println!(
            "added {:<24} held-out {:.4} -> {:.4} deg, {:.4} -> {:.4} mm",
            s.effect, s.rms_rot_deg_before, s.rms_rot_deg_after, s.rms_trans_mm_before, s.rms_trans_mm_after
        );
        if let Some(f) = &s.form {
            println!("  as {f}");
        }
        if let Some(w) = &s.warning {
            println!("  warning: {w}");
        }
    }
    for a in &r.ambiguous {
        println!("ambiguous between {}: {}", a.effects.join(" and "), a.evidence);
    }
    for b in &r.at_bounds {
        println!(
            "at a plausibility bound: {} = {:.4} (bound {:.4}); probably absorbing {}",
            b.param, b.value, b.bound, b.absorbing
        );
    }
    println!(
        "final held-out {:.4} deg ({:.2}x the floor) / {:.4} mm ({:.2}x)",
        r.final_rms.0,
        r.final_rms.0 / r.noise_floor_rot_deg,
        r.final_rms.1,
        r.final_rms.1 / r.noise_floor_trans_mm
    );
    for u in &r.unexplained {
        println!("unexplained: {} ({:.4} deg rms)", u.description, u.rms_rot_deg);
    }
    println!("{:.1} s; report in {}", t0.elapsed().as_secs_f64(), a.out.join("report.md").display());
    Ok(ExitCode::SUCCESS)
}
