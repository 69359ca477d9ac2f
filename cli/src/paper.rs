//! `abvs calib paper`: the paper's experiments on the simulated units C0..C3, one report.
use abvs_paper::{run_paper, PaperConfig};
use clap::Args;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Args)]
pub struct PaperArgs {
    /// Report directory: report.md, summary.json and PNG figures.
    #[arg(long)]
    out: PathBuf,
    /// Seed of every simulated session and of training.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Smaller grids, fewer epochs and sizes, C1 only: a smoke test in well under a minute.
    #[arg(long)]
    quick: bool,
    /// Maximum training epochs (1 to 1000000; default: 1000, or 100 with --quick).
    #[arg(long, value_parser = crate::args::count(1usize, 1_000_000))]
    max_epochs: Option<usize>,
    /// Keep every trained model under OUT/models/ (removed by default).
    #[arg(long)]
    keep_models: bool,
}

pub fn run(a: PaperArgs) -> anyhow::Result<ExitCode> {
    let mut cfg = if a.quick { PaperConfig::quick(a.seed) } else { PaperConfig::full(a.seed) };
    if let Some(n) = a.max_epochs {
        cfg.max_epochs = n;
    }
    cfg.keep_models = a.keep_models;
    let s = run_paper(&cfg, &a.out, &mut |line| eprintln!("{line}"))?;
    for c in &s.conclusions {
        println!("{}: {}", c.verdict, c.claim);
    }
    println!("wrote {} ({:.0} s)", a.out.join("report.md").display(), s.seconds);
    Ok(ExitCode::SUCCESS)
}
