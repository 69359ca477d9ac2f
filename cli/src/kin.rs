//! `abvs kin`: kinematics on CSV tables. Columns are found by name, all other columns are
//! kept; a row that cannot be solved is reported by its line and left with empty outputs, and
//! the command exits non-zero if any row failed.
use abvs_eye::psc::{percentile, psc_map};
use abvs_eye::unit::{Conditions, MotionHistory};
use abvs_eye::{Fick, SpmGeometry, UnitModel};
use anyhow::Context;
use clap::{Args, Subcommand};
use std::path::{Path, PathBuf};
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
    #[arg(long = "in")]
    input: PathBuf,
    #[arg(long)]
    out: PathBuf,
}

#[derive(Args)]
pub struct FkArgs {
    #[arg(long = "in")]
    input: PathBuf,
    #[arg(long)]
    out: PathBuf,
    /// Unit model (TOML); nominal geometry with the camera at O1 when absent.
    #[arg(long)]
    unit: Option<PathBuf>,
}

#[derive(Args)]
pub struct PscArgs {
    #[arg(long, default_value_t = 2.0)]
    step_deg: f64,
    #[arg(long)]
    out: PathBuf,
    /// Heatmap over alpha x gamma (max over beta) as PNG.
    #[arg(long)]
    png: Option<PathBuf>,
}

/// A CSV table held as strings, so unknown columns pass through untouched.
struct Table {
    header: Vec<String>,
    rows: Vec<Vec<String>>,
}

impl Table {
    fn read(path: &Path) -> anyhow::Result<Table> {
        let mut rd = csv::ReaderBuilder::new()
            .trim(csv::Trim::All)
            .from_path(path)
            .with_context(|| format!("{}: cannot open", path.display()))?;
        let header: Vec<String> = rd
            .headers()
            .with_context(|| format!("{}:1: bad header", path.display()))?
            .iter()
            .map(String::from)
            .collect();
        let mut rows = Vec::new();
        for (k, rec) in rd.records().enumerate() {
            let rec = rec.map_err(|e| anyhow::anyhow!("{}:{}: {e}", path.display(), k + 2))?;
            rows.push(rec.iter().map(String::from).collect());
        }
        Ok(Table { header, rows })
    }

    fn col(&self, path: &Path, name: &str) -> anyhow::Result<usize> {
        self.header
            .iter()
            .position(|h| h == name)
            .ok_or_else(|| anyhow::anyhow!("{}:1: missing column {name}", path.display()))
    }

    /// Index of an output column, appended if absent.
    fn out_col(&mut self, name: &str) -> usize {
        match self.header.iter().position(|h| h == name) {
            Some(i) => i,
            None => {
                self.header.push(name.into());
                for r in &mut self.rows {
                    r.push(String::new());
                }
                self.header.len() - 1
            }
        }
    }

    fn write(&self, path: &Path) -> anyhow::Result<()> {
        let mut w = csv::Writer::from_path(path)
            .with_context(|| format!("{}: cannot create", path.display()))?;
        w.write_record(&self.header)?;
        for r in &self.rows {
            w.write_record(r)?;
        }
        w.flush()?;
        Ok(())
    }
}

fn num(path: &Path, line: usize, col: &str, s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => Err(format!(
            "{}:{line}: column {col}: not a finite number",
            path.display()
        )),
        Err(_) => Err(format!(
            "{}:{line}: column {col}: \"{s}\" is not a number",
            path.display()
        )),
    }
}

/// Applies `f` to the named input columns of each row and fills the named output columns.
fn map_rows(
    input: &Path,
    out: &Path,
    inputs: &[&str],
    outputs: &[&str],
    mut f: impl FnMut(&[f64], usize) -> Result<Vec<f64>, String>,
) -> anyhow::Result<ExitCode> {
    let mut t = Table::read(input)?;
    let ic: Vec<usize> = inputs
        .iter()
        .map(|n| t.col(input, n))
        .collect::<anyhow::Result<_>>()?;
    let oc: Vec<usize> = outputs.iter().map(|n| t.out_col(n)).collect();
    let mut failed = 0usize;
    for (k, row) in t.rows.iter_mut().enumerate() {
        let line = k + 2;
        let vals: Result<Vec<f64>, String> = ic
            .iter()
            .zip(inputs)
            .map(|(&c, n)| num(input, line, n, &row[c]))
            .collect();
        let res =
            vals.and_then(|v| f(&v, line).map_err(|e| format!("{}:{line}: {e}", input.display())));
        match res {
            Ok(o) => {
                for (c, v) in oc.iter().zip(o) {
                    row[*c] = format!("{v}");
                }
            }
            Err(e) => {
                failed += 1;
                eprintln!("error: {e}");
                for c in &oc {
                    row[*c].clear();
                }
            }
        }
    }
    t.write(out)?;
    if failed > 0 {
        eprintln!(
            "{failed} of {} rows failed; {} written with those rows' outputs empty",
            t.rows.len(),
            out.display()
        );
        Ok(ExitCode::FAILURE)
    } else {
        eprintln!("wrote {} ({} rows)", out.display(), t.rows.len());
        Ok(ExitCode::SUCCESS)
    }
}

pub fn run(cmd: KinCmd) -> anyhow::Result<ExitCode> {
    match cmd {
        KinCmd::Ik(a) => {
            let g = SpmGeometry::nominal();
            map_rows(
                &a.input,
                &a.out,
                &["alpha_deg", "beta_deg", "gamma_deg"],
                &["theta1_deg", "theta2_deg", "theta3_deg"],
                |v, _| {
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
            let mut hist = MotionHistory::new();
            let mut warm = fk.home_platform();
            let t = Table::read(&a.input)?;
            let g_cols: Option<Vec<usize>> = ["gx", "gy", "gz"]
                .iter()
                .map(|n| t.header.iter().position(|h| h == n))
                .collect();
            let rows = t.rows;
            map_rows(
                &a.input,
                &a.out,
                &["theta1_deg", "theta2_deg", "theta3_deg"],
                &["alpha_deg", "beta_deg", "gamma_deg", "x_mm", "y_mm", "z_mm"],
                |v, line| {
                    let q = [v[0], v[1], v[2]];
                    let mut cond = Conditions {
                        dir: hist.update(&q),
                        ..Default::default()
                    };
                    if let Some(gc) = &g_cols {
                        let row = &rows[line - 2];
                        for (k, c) in gc.iter().enumerate() {
                            cond.gravity[k] = num(&a.input, line, ["gx", "gy", "gz"][k], &row[*c])
                                .map_err(|e| {
                                    e.split(": ").skip(1).collect::<Vec<_>>().join(": ")
                                })?;
                        }
                    }
                    let (p, r) = fk.pose(&q, &cond, Some(&warm)).map_err(|e| e.to_string())?;
                    warm = r;
                    Ok(p.to_p6().to_vec())
                },
            )
        }
        KinCmd::Psc(a) => {
            let g = SpmGeometry::nominal();
            let map = psc_map(&g, a.step_deg);
            let mut w = csv::Writer::from_path(&a.out)
                .with_context(|| format!("{}: cannot create", a.out.display()))?;
            w.write_record([
                "alpha_deg",
                "beta_deg",
                "gamma_deg",
                "theta1_deg",
                "theta2_deg",
                "theta3_deg",
                "psc",
            ])?;
            for p in &map {
                let mut rec: Vec<String> = p
                    .fick_deg
                    .iter()
                    .chain(&p.theta_deg)
                    .map(|x| format!("{x}"))
                    .collect();
                rec.push(format!("{}", p.s));
                w.write_record(&rec)?;
            }
            w.flush()?;
            let s: Vec<f64> = map.iter().map(|p| p.s).collect();
            eprintln!(
                "PSC over {} poses: min {:.4}, p10 {:.4}, p50 {:.4}, p90 {:.4}, max {:.4} (rad/deg)",
                s.len(),
                percentile(&s, 0.0),
                percentile(&s, 0.1),
                percentile(&s, 0.5),
                percentile(&s, 0.9),
                percentile(&s, 1.0)
            );
            if let Some(png) = a.png {
                let pts: Vec<(f64, f64, f64)> = map
                    .iter()
                    .map(|p| (p.fick_deg[0], p.fick_deg[2], p.s))
                    .collect();
                crate::plot::heatmap_max(
                    &pts,
                    a.step_deg,
                    &png,
                    "PSC S (rad/deg), max over beta: alpha (rows) x gamma (cols)",
                )?;
                eprintln!("wrote {}", png.display());
            }
            Ok(ExitCode::SUCCESS)
        }
    }
}
