//! `abvs demo`: the main job until the runtime lands. On the embedded default unit
//! (fixtures/units/c0.toml, compiled into the binary) it simulates the paper's 3 deg data
//! collection, compares the nominal kinematics and the unit's true model with the measurements,
//! maps the PSC, and writes CSV, PNG and a JSON summary (the analysis: `abvs_calib::demo`).
use abvs_calib::demo::{compare_kinematics, fit_and_score, held_out_session};
use abvs_calib::methods::Method;
use abvs_eye::psc::{psc_map, spread};
use abvs_eye::sim::{simulate_dataset, Commanded, SimSpec};
use abvs_eye::{SpmGeometry, UnitModel};
use anyhow::Context;
use clap::Args;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

/// The embedded default unit (a copy of fixtures/units/c0.toml).
pub const DEFAULT_UNIT: &str = include_str!("../../fixtures/units/c0.toml");

#[derive(Args)]
pub struct DemoArgs {
    /// Unit model (default: the embedded fixtures/units/c0.toml).
    #[arg(long)]
    unit: Option<PathBuf>,
    /// Output directory (CSV, PNG heatmaps, model, summary.json).
    #[arg(long, default_value = "out/demo")]
    out: PathBuf,
    /// Grid step of the simulated data collection and the PSC map (deg; the grid may hold at most 2e6 poses).
    #[arg(long, default_value_t = 3.0, value_parser = crate::args::positive_up_to(30.0))]
    step_deg: f64,
    /// Seed of the simulated measurements and of the fit.
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

impl DemoArgs {
    /// The grid's size and the output directory before any work.
    pub fn check(&self) -> anyhow::Result<()> {
        crate::args::check_grid("--step-deg", abvs_eye::WORKSPACE_DEG, self.step_deg)?;
        Ok(abvs_runtime::outputs::check_dir_creatable("--out", &self.out)?)
    }
}

pub fn run(a: DemoArgs) -> anyhow::Result<ExitCode> {
    let unit = match &a.unit {
        Some(p) => UnitModel::load(p)?,
        None => UnitModel::from_toml_str(DEFAULT_UNIT, Path::new("fixtures/units/c0.toml (embedded)"))?,
    };
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    println!(
        "abvs demo: unit '{}' ({} effects on), output in {}",
        unit.name,
        unit.enabled_effects().len(),
        a.out.display()
    );

    let t0 = Instant::now();
    let spec = SimSpec { commanded: Commanded::Step(a.step_deg), seed: a.seed, ..Default::default() };
    let pb = crate::progress_bar(0, "simulating");
    let (data, stats) = simulate_dataset(&unit, &spec, crate::progress_to(&pb))?;
    pb.finish_and_clear();
    let data_path = a.out.join(format!("dataset_{}deg.csv", a.step_deg));
    data.write(&data_path)?;
    let t_sim = t0.elapsed().as_secs_f64();
    println!(
        "simulated {} of {} commanded poses ({} failed measurements) in {:.2} s -> {}",
        stats.written,
        stats.commanded,
        stats.failed_measurement,
        t_sim,
        data_path.display()
    );

    let cmp = compare_kinematics(&unit, &data)?;
    println!("\nmean |error| vs measured     alpha   beta  gamma (deg)      x      y      z (mm)   rot   trans");
    for (name, e) in [("nominal kinematics", &cmp.nominal), ("true unit model (floor)", &cmp.true_model)] {
        let m = e.mean_abs;
        println!(
            "{name:<25}{:>9.3} {:>6.3} {:>6.3}       {:>9.3} {:>6.3} {:>6.3}   {:>6.3} {:>6.3}",
            m[0], m[1], m[2], m[3], m[4], m[5], e.rot_norm_mean_deg, e.trans_norm_mean_mm
        );
    }

    // Where the nominal model is off: rotation deviation over alpha x gamma (max over beta).
    let dev_png = a.out.join("nominal_error_heatmap.png");
    crate::plot::workspace_heatmap(
        &dev_png,
        "nominal kinematics vs measured (max over roll)",
        "rotation error, deg",
        &cmp.nominal_rotation_error,
        a.step_deg,
        abvs_plot::Reduce::Max,
    )?;

    let t1 = Instant::now();
    let map = psc_map(&SpmGeometry::nominal(), a.step_deg);
    let s = spread(&map);
    let psc_png = a.out.join("psc_heatmap.png");
    crate::plot::workspace_heatmap(
        &psc_png,
        "pose sensitivity coefficient (max over roll)",
        "S, rad/deg",
        &map.iter().map(|p| (p.fick_deg[0], p.fick_deg[2], p.s)).collect::<Vec<_>>(),
        a.step_deg,
        abvs_plot::Reduce::Max,
    )?;
    println!(
        "\nPSC over {} poses ({:.2} s): min {:.4}, median {:.4}, max {:.4} rad/deg",
        map.len(),
        t1.elapsed().as_secs_f64(),
        s.min,
        s.median,
        s.max
    );
    println!("heatmaps (gamma across, alpha up): {}, {}", dev_png.display(), psc_png.display());

    // Calibration: hand-eye and the physics-based hybrid from the 3 deg set, scored on a
    // separate random session (the networks of the paper take minutes: `abvs calib paper`).
    let test = held_out_session(&unit, a.seed)?;
    println!(
        "
calibrated FK on {} held-out poses (mean |error|)   rot (deg)  trans (mm)   MPE (px)",
        test.len()
    );
    let mut calib = serde_json::Map::new();
    for method in [Method::Mh, Method::Hybrid] {
        let s = fit_and_score(method, &data, &test, &a.out.join(format!("model_{}", method.name())))?;
        let r = &s.report;
        println!(
            "{:<8} fitted in {:>5.2} s                       {:>9.4} {:>11.4} {:>10.3}",
            method.name(),
            s.seconds,
            r.rot_norm_mean_deg,
            r.trans_norm_mean_mm,
            r.mpe_px
        );
        calib.insert(method.name().into(), serde_json::to_value(r)?);
    }

    let summary = serde_json::json!({
        "calibration_test": calib,
        "unit": unit.name,
        "samples": stats.written,
        "commanded": stats.commanded,
        "max_dev_rot_deg": stats.max_dev_rot_deg,
        "max_dev_trans_mm": stats.max_dev_trans_mm,
        "nominal": cmp.nominal,
        "true_model": cmp.true_model,
        "psc": {"min": s.min, "median": s.median, "max": s.max},
        "seconds": {"simulate": t_sim},
    });
    let sp = a.out.join("summary.json");
    std::fs::write(&sp, serde_json::to_string_pretty(&summary)?)
        .with_context(|| format!("writing {}", sp.display()))?;
    println!("summary: {}", sp.display());
    Ok(ExitCode::SUCCESS)
}
