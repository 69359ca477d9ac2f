//! `abvs demo`: the main job until the runtime lands. On the embedded default unit
//! (fixtures/units/c0.toml, compiled into the binary) it simulates the paper's 3 deg data
//! collection, compares the nominal kinematics and the unit's true model with the measurements,
//! maps the PSC, and writes CSV, PNG and a JSON summary.
use abvs_calib::methods::{self, FitConfig, Method};
use abvs_calib::metrics::evaluate;
use abvs_calib::model::{save_model, FkModel};
use abvs_calib::mpe::Target;
use abvs_eye::pose::rotation_angle_deg;
use abvs_eye::psc::{percentile, psc_map};
use abvs_eye::sim::{simulate_dataset, Commanded, SimSpec};
use abvs_eye::{Pose, SpmGeometry, UnitModel};
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

/// Mean |error| per axis and mean rotation / translation error norms.
fn errors(pred: &[[f64; 6]], meas: &[[f64; 6]]) -> ([f64; 6], f64, f64) {
    let mut m = [0.0; 6];
    let (mut rn, mut tn) = (0.0, 0.0);
    for (p, q) in pred.iter().zip(meas) {
        for k in 0..6 {
            m[k] += (p[k] - q[k]).abs();
        }
        let (a, b) = (Pose::from_p6(p), Pose::from_p6(q));
        rn += rotation_angle_deg(&a.r, &b.r);
        tn += (a.t - b.t).norm();
    }
    let n = pred.len().max(1) as f64;
    (m.map(|x| x / n), rn / n, tn / n)
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
    let (data, stats) = simulate_dataset(&unit, &spec, |d, t| {
        pb.set_length(t as u64);
        pb.set_position(d as u64);
    })?;
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

    let meas: Vec<[f64; 6]> = data.samples.iter().map(|s| s.pose).collect();
    let nominal = UnitModel::nominal().compile()?.predict_dataset(&data)?;
    let truth = unit.compile()?.predict_dataset(&data)?;
    let (en, rn, tn) = errors(&nominal, &meas);
    let (et, rt, tt) = errors(&truth, &meas);
    println!("\nmean |error| vs measured     alpha   beta  gamma (deg)      x      y      z (mm)   rot   trans");
    println!(
        "nominal kinematics       {:>9.3} {:>6.3} {:>6.3}       {:>9.3} {:>6.3} {:>6.3}   {:>6.3} {:>6.3}",
        en[0], en[1], en[2], en[3], en[4], en[5], rn, tn
    );
    println!(
        "true unit model (floor)  {:>9.3} {:>6.3} {:>6.3}       {:>9.3} {:>6.3} {:>6.3}   {:>6.3} {:>6.3}",
        et[0], et[1], et[2], et[3], et[4], et[5], rt, tt
    );

    // Where the nominal model is off: rotation deviation over alpha x gamma (max over beta).
    let dev: Vec<(f64, f64, f64)> = data
        .samples
        .iter()
        .zip(&nominal)
        .map(|(s, p)| {
            let c = s.cmd_deg.unwrap_or([s.pose[0], s.pose[1], s.pose[2]]);
            (c[0], c[2], rotation_angle_deg(&Pose::from_p6(p).r, &Pose::from_p6(&s.pose).r))
        })
        .collect();
    let dev_png = a.out.join("nominal_error_heatmap.png");
    crate::plot::workspace_heatmap(
        &dev_png,
        "nominal kinematics vs measured (max over roll)",
        "rotation error, deg",
        &dev,
        a.step_deg,
        abvs_plot::Reduce::Max,
    )?;

    let t1 = Instant::now();
    let map = psc_map(&SpmGeometry::nominal(), a.step_deg);
    let s: Vec<f64> = map.iter().map(|p| p.s).collect();
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
        s.len(),
        t1.elapsed().as_secs_f64(),
        percentile(&s, 0.0),
        percentile(&s, 0.5),
        percentile(&s, 1.0)
    );
    println!("heatmaps (gamma across, alpha up): {}, {}", dev_png.display(), psc_png.display());

    // Calibration: hand-eye and the physics-based hybrid from the 3 deg set, scored on a
    // separate random session (the networks of the paper take minutes: `abvs calib paper`).
    let test_spec =
        SimSpec { commanded: Commanded::Step(1.0), random: Some(2000), seed: a.seed + 1, ..Default::default() };
    let (test, _) = simulate_dataset(&unit, &test_spec, |_, _| {})?;
    let test_meas: Vec<[f64; 6]> = test.samples.iter().map(|s| s.pose).collect();
    println!(
        "
calibrated FK on {} held-out poses (mean |error|)   rot (deg)  trans (mm)   MPE (px)",
        test.len()
    );
    let mut calib = serde_json::Map::new();
    for method in [Method::Mh, Method::Hybrid] {
        let t = Instant::now();
        let parts = methods::fit(method, &data, None, &FitConfig::default(), &mut |_, _, _, _, _| {})?;
        let dir = a.out.join(format!("model_{}", method.name()));
        save_model(&dir, &parts)?;
        let model = FkModel::load(&dir)?;
        let r = evaluate(&model.predict_dataset(&test)?, &test_meas, &Target::paper());
        println!(
            "{:<8} fitted in {:>5.2} s                       {:>9.4} {:>11.4} {:>10.3}",
            method.name(),
            t.elapsed().as_secs_f64(),
            r.rot_norm_mean_deg,
            r.trans_norm_mean_mm,
            r.mpe_px
        );
        calib.insert(method.name().into(), serde_json::to_value(&r)?);
    }

    let summary = serde_json::json!({
        "calibration_test": calib,
        "unit": unit.name,
        "samples": stats.written,
        "commanded": stats.commanded,
        "max_dev_rot_deg": stats.max_dev_rot_deg,
        "max_dev_trans_mm": stats.max_dev_trans_mm,
        "nominal": {"mean_abs": en, "rot_norm_mean_deg": rn, "trans_norm_mean_mm": tn},
        "true_model": {"mean_abs": et, "rot_norm_mean_deg": rt, "trans_norm_mean_mm": tt},
        "psc": {"min": percentile(&s, 0.0), "median": percentile(&s, 0.5), "max": percentile(&s, 1.0)},
        "seconds": {"simulate": t_sim},
    });
    let sp = a.out.join("summary.json");
    std::fs::write(&sp, serde_json::to_string_pretty(&summary)?)
        .with_context(|| format!("writing {}", sp.display()))?;
    println!("summary: {}", sp.display());
    Ok(ExitCode::SUCCESS)
}
