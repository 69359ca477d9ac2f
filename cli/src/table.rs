//! CSV tables held as strings, so unknown columns pass through untouched, and the row-by-row
//! mapping shared by `kin` and `calib predict`: columns found by name, a bad row reported by its
//! line and left with empty outputs, non-zero exit if any row failed.
use anyhow::Context;
use std::path::Path;
use std::process::ExitCode;

/// A CSV table held as strings, so unknown columns pass through untouched.
pub struct Table {
    pub header: Vec<String>,
    pub rows: Vec<Vec<String>>,
}

impl Table {
    pub fn read(path: &Path) -> anyhow::Result<Table> {
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

    pub fn col(&self, path: &Path, name: &str) -> anyhow::Result<usize> {
        self.header
            .iter()
            .position(|h| h == name)
            .ok_or_else(|| anyhow::anyhow!("{}:1: missing column {name}", path.display()))
    }

    /// Index of an output column, appended if absent.
    pub fn out_col(&mut self, name: &str) -> usize {
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

    pub fn write(&self, path: &Path) -> anyhow::Result<()> {
        let mut w = csv::Writer::from_path(path).with_context(|| format!("{}: cannot create", path.display()))?;
        w.write_record(&self.header)?;
        for r in &self.rows {
            w.write_record(r)?;
        }
        w.flush()?;
        Ok(())
    }
}

pub fn num(path: &Path, line: usize, col: &str, s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => Err(format!("{}:{line}: column {col}: not a finite number", path.display())),
        Err(_) => Err(format!("{}:{line}: column {col}: \"{s}\" is not a number", path.display())),
    }
}

/// Gravity of a row from optional gx, gy, gz columns (dataset.md: absent means head upright).
pub struct GravityCols(Option<[usize; 3]>);

impl GravityCols {
    pub fn find(t: &Table) -> Self {
        let idx: Option<Vec<usize>> = ["gx", "gy", "gz"].iter().map(|n| t.header.iter().position(|h| h == n)).collect();
        GravityCols(idx.map(|v| [v[0], v[1], v[2]]))
    }
    pub fn of(&self, path: &Path, line: usize, row: &[String]) -> Result<[f64; 3], String> {
        let Some(c) = self.0 else { return Ok([0.0, 1.0, 0.0]) };
        let mut g = [0.0; 3];
        for k in 0..3 {
            g[k] = num(path, line, ["gx", "gy", "gz"][k], &row[c[k]])?;
        }
        // as the simulator and sessions demand: a zero or scaled vector would change the modelled sag
        let norm = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
        if (norm - 1.0).abs() > 1e-3 {
            return Err(format!(
                "{}:{line}: columns gx, gy, gz: {g:?} has length {norm:.4}, expected a unit vector",
                path.display()
            ));
        }
        Ok(g)
    }
}

/// Applies `f(inputs, line, whole row)` to each row of `t` (read from `input`) and fills the
/// named output columns; writes `out`.
pub fn map_rows(
    mut t: Table,
    input: &Path,
    out: &Path,
    inputs: &[&str],
    outputs: &[&str],
    mut f: impl FnMut(&[f64], usize, &[String]) -> Result<Vec<f64>, String>,
) -> anyhow::Result<ExitCode> {
    let ic: Vec<usize> = inputs.iter().map(|n| t.col(input, n)).collect::<anyhow::Result<_>>()?;
    let oc: Vec<usize> = outputs.iter().map(|n| t.out_col(n)).collect();
    if t.rows.is_empty() {
        // nothing computed is not a success
        anyhow::bail!("{}: no rows to compute (a header without data)", input.display());
    }
    let mut failed = 0usize;
    for (k, row) in t.rows.iter_mut().enumerate() {
        let line = k + 2;
        let vals: Result<Vec<f64>, String> =
            ic.iter().zip(inputs).map(|(&c, n)| num(input, line, n, &row[c])).collect();
        let res = vals.and_then(|v| {
            f(&v, line, row).map_err(|e| {
                if e.starts_with(&input.display().to_string()) {
                    e
                } else {
                    format!("{}:{line}: {e}", input.display())
                }
            })
        });
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
        eprintln!("{failed} of {} rows failed; {} written with those rows' outputs empty", t.rows.len(), out.display());
        Ok(ExitCode::FAILURE)
    } else {
        eprintln!("wrote {} ({} rows)", out.display(), t.rows.len());
        Ok(ExitCode::SUCCESS)
    }
}
