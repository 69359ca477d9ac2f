//! `abvs sim repeatability` (the ISO 9283 protocol on a unit) and `abvs calib repeatability`
//! (ISO 9283 statistics of a session, the paper's Table I layout).
use abvs_calib::repeatability::{repeatability, table};
use abvs_eye::dataset::Dataset;
use abvs_eye::sim::{iso9283_targets, simulate_repeatability, RepeatSpec};
use abvs_eye::{UnitModel, WORKSPACE_DEG};
use clap::Args;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Args)]
pub struct SimRepeatArgs {
    /// Unit model to simulate (TOML).
    #[arg(long)]
    unit: PathBuf,
    /// Measured session (dataset CSV with target, approach and image columns).
    #[arg(long)]
    out: PathBuf,
    /// The same rows with the true, noise-free poses.
    #[arg(long)]
    truth: Option<PathBuf>,
    /// Approaches per target, each from a random start (ISO 9283: 30; 1 to 1000).
    #[arg(long, default_value_t = 30, value_parser = crate::args::count(1usize, 1000))]
    approaches: usize,
    /// Images per approach (the links standing still; 1 to 100).
    #[arg(long, default_value_t = 10, value_parser = crate::args::count(1usize, 100))]
    images: usize,
    /// The servo stops within this many encoder counts of the command (0 to 1000).
    #[arg(long, default_value_t = 2, value_parser = crate::args::count(0i64, 1000))]
    settle_counts: i64,
    /// Targets "a,b,g;a,b,g;..." (Fick deg); default ISO 9283's P1..P5 on the workspace.
    #[arg(long, allow_hyphen_values = true)]
    targets: Option<String>,
    /// Measurement noise "rot_deg,trans_mm" instead of the unit's own (e.g. a laser tracker).
    #[arg(long, value_parser = parse2)]
    measurement: Option<(f64, f64)>,
    /// Seed of the random starts and the noise.
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

/// "rot_deg,trans_mm": two finite standard deviations, each in [0, 10].
fn parse2(s: &str) -> Result<(f64, f64), String> {
    let [a, b] = crate::args::vec2(s).map_err(|e| format!("{e} (rot_deg,trans_mm)"))?;
    if !((0.0..=10.0).contains(&a) && (0.0..=10.0).contains(&b)) {
        return Err(format!("'{s}': each of rot_deg,trans_mm must be in [0, 10]"));
    }
    Ok((a, b))
}

#[derive(Args)]
pub struct RepeatArgs {
    /// Session: dataset CSV with the commanded pose of each row (cmd_*), optionally target/approach columns.
    #[arg(long)]
    data: PathBuf,
    /// Print JSON instead of the table.
    #[arg(long)]
    json: bool,
}

pub fn sim(a: SimRepeatArgs) -> anyhow::Result<ExitCode> {
    let unit = UnitModel::load(&a.unit)?;
    let targets = match &a.targets {
        Some(t) => crate::parse_list(t)?,
        None => iso9283_targets(WORKSPACE_DEG),
    };
    let spec = RepeatSpec {
        targets,
        approaches: a.approaches,
        images: a.images,
        settle_counts: a.settle_counts,
        measurement: a.measurement,
        seed: a.seed,
        ..RepeatSpec::default()
    };
    let s = simulate_repeatability(&unit, &spec)?;
    s.measured.write(&a.out)?;
    eprintln!(
        "wrote {} ({} targets x {} approaches x {} images)",
        a.out.display(),
        spec.targets.len(),
        spec.approaches,
        spec.images
    );
    if let Some(t) = &a.truth {
        s.truth.write(t)?;
        eprintln!("wrote {} (true poses)", t.display());
    }
    Ok(ExitCode::SUCCESS)
}

pub fn stats(a: RepeatArgs) -> anyhow::Result<ExitCode> {
    let data = Dataset::read(&a.data)?;
    let rows = repeatability(&data)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    } else {
        println!("repeatability (ISO 9283) of {}", a.data.display());
        print!("{}", table(&rows));
    }
    Ok(ExitCode::SUCCESS)
}
