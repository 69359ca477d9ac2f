//! `abvs kin`: kinematics on CSV tables. Columns are found by name, all other columns are
//! kept; a row that cannot be solved is reported by its line and left with empty outputs, and
//! the command exits non-zero if any row failed.
use crate::table::map_rows;
use abvs_eye::psc::{psc_map, spread, write_csv};
use abvs_eye::table::{GravityCols, Table};
use abvs_eye::{Fick, SpmGeometry, UnitModel};
use clap::{Args, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Subcommand)]
pub enum KinCmd {
    /// Nominal IK: alpha_deg, beta_deg, gamma_deg -> theta1_deg, theta2_deg, theta3_deg.
    Ik(IoArgs),
    /// FK: theta1_deg.. -> alpha_deg, beta_deg, gamma_deg, x_mm, y_mm, z_mm (nominal, or a unit).
    Fk(FkArgs),
    /// The pose sensitivity coefficient S over the workspace grid (CSV + PNG heatmap).
    Psc(PscArgs),
}

#[derive(Args)]
pub struct IoArgs {
    /// Input CSV with alpha_deg, beta_deg, gamma_deg columns (deg; other columns kept).
    #[arg(long = "in")]
    input: PathBuf,
    /// Output CSV: the input's columns plus theta1_deg..theta3_deg.
    #[arg(long)]
    out: PathBuf,
}

#[derive(Args)]
pub struct FkArgs {
    /// Input CSV with theta1_deg..theta3_deg columns (deg; optional gx, gy, gz; other columns kept).
    #[arg(long = "in")]
    input: PathBuf,
    /// Output CSV: the input's columns plus the pose (alpha/beta/gamma deg, x/y/z mm).
    #[arg(long)]
    out: PathBuf,
    /// Unit model (TOML); nominal geometry with the camera at O1 when absent.
    #[arg(long)]
    unit: Option<PathBuf>,
}

#[derive(Args)]
pub struct PscArgs {
    /// Grid step over the workspace (deg; a grid of at most 2e6 poses: from about 0.38 deg).
    #[arg(long, default_value_t = 2.0, value_parser = crate::args::positive_up_to(30.0))]
    step_deg: f64,
    /// Output CSV: Fick angles, link angles and S per pose.
    #[arg(long)]
    out: PathBuf,
    /// Heatmap over alpha x gamma (max over beta) as PNG.
    #[arg(long)]
    png: Option<PathBuf>,
}

impl PscArgs {
    /// The grid's size, before any work.
    pub fn check(&self) -> anyhow::Result<()> {
        crate::args::check_grid("--step-deg", abvs_eye::WORKSPACE_DEG, self.step_deg)
    }
}

pub fn run(cmd: KinCmd) -> anyhow::Result<ExitCode> {
    match cmd {
        KinCmd::Ik(a) => {
            let g = SpmGeometry::nominal();
            map_rows(
                Table::read(&a.input)?,
                &a.input,
                &a.out,
                &["alpha_deg", "beta_deg", "gamma_deg"],
                &["theta1_deg", "theta2_deg", "theta3_deg"],
                |v, _, _| {
                    let r = Fick::from_deg([v[0], v[1], v[2]]).to_matrix();
                    let th = g.ik_checked(&r).map_err(|e| e.to_string())?;
                    Ok(th.iter().map(|t| t.to_degrees()).collect())
                },
            )
        }
        KinCmd::Fk(a) => {
            let unit = match &a.unit {
                Some(p) => UnitModel::load(p)?,
                None => UnitModel::nominal(),
            };
            let fk = unit.compile()?;
            // Rows are a motion history (backlash): walk them in order; gravity per row if given.
            let mut stream = fk.stream();
            let t = Table::read(&a.input)?;
            let gcols = GravityCols::find(&t);
            map_rows(
                t,
                &a.input,
                &a.out,
                &["theta1_deg", "theta2_deg", "theta3_deg"],
                &["alpha_deg", "beta_deg", "gamma_deg", "x_mm", "y_mm", "z_mm"],
                |v, line, row| {
                    let g = gcols.of(&a.input, line, row)?;
                    Ok(fk.next(&mut stream, &[v[0], v[1], v[2]], g).map_err(|e| e.to_string())?.to_p6().to_vec())
                },
            )
        }
        KinCmd::Psc(a) => {
            let g = SpmGeometry::nominal();
            let map = psc_map(&g, a.step_deg);
            write_csv(&map, &a.out)?;
            let s = spread(&map);
            eprintln!(
                "PSC over {} poses: min {:.4}, p10 {:.4}, p50 {:.4}, p90 {:.4}, max {:.4} (rad/deg)",
                map.len(),
                s.min,
                s.p10,
                s.median,
                s.p90,
                s.max
            );
            if let Some(png) = a.png {
                let pts: Vec<(f64, f64, f64)> = map.iter().map(|p| (p.fick_deg[0], p.fick_deg[2], p.s)).collect();
                crate::plot::workspace_heatmap(
                    &png,
                    "pose sensitivity coefficient (max over roll)",
                    "S, rad/deg",
                    &pts,
                    a.step_deg,
                    abvs_plot::Reduce::Max,
                )?;
                eprintln!("wrote {}", png.display());
            }
            Ok(ExitCode::SUCCESS)
        }
    }
}
