//! CSV tables held as strings, so unknown columns pass through untouched, and the row-by-row mapping of
//! `abvs kin` and `abvs calib predict | ik`: columns found by name, each row's inputs parsed as finite
//! numbers, a bad row named by its line and left with empty outputs.
use std::path::Path;

use crate::error::{EyeError, Result};

/// A CSV table held as strings, so unknown columns pass through untouched.
#[derive(Debug, Clone, PartialEq)]
pub struct Table {
    /// Column names.
    pub header: Vec<String>,
    /// Rows, each as long as the header.
    pub rows: Vec<Vec<String>>,
}

impl Table {
    /// Reads a CSV file (fields trimmed); errors name the file and line.
    pub fn read(path: &Path) -> Result<Table> {
        let mut rd = csv::ReaderBuilder::new()
            .trim(csv::Trim::All)
            .from_path(path)
            .map_err(|e| EyeError::file(path, None, format!("cannot open: {e}")))?;
        let header: Vec<String> = rd
            .headers()
            .map_err(|e| EyeError::file(path, Some(1), format!("bad header: {e}")))?
            .iter()
            .map(String::from)
            .collect();
        let mut rows = Vec::new();
        for (k, rec) in rd.records().enumerate() {
            let rec = rec.map_err(|e| EyeError::file(path, Some(k + 2), e.to_string()))?;
            rows.push(rec.iter().map(String::from).collect());
        }
        Ok(Table { header, rows })
    }

    /// Index of the column `name` of the table read from `path`.
    pub fn col(&self, path: &Path, name: &str) -> Result<usize> {
        self.header
            .iter()
            .position(|h| h == name)
            .ok_or_else(|| EyeError::file(path, Some(1), format!("missing column {name}")))
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

    /// Writes the table as CSV.
    pub fn write(&self, path: &Path) -> Result<()> {
        let io = |e: csv::Error| EyeError::file(path, None, format!("cannot create: {e}"));
        let mut w = csv::Writer::from_path(path).map_err(io)?;
        w.write_record(&self.header).map_err(io)?;
        for r in &self.rows {
            w.write_record(r).map_err(io)?;
        }
        w.flush().map_err(|e| EyeError::io(path, e))
    }
}

/// A finite number from field `col` at `line`, or why not.
pub fn num(path: &Path, line: usize, col: &str, s: &str) -> std::result::Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => Err(format!("{}:{line}: column {col}: not a finite number", path.display())),
        Err(_) => Err(format!("{}:{line}: column {col}: \"{s}\" is not a number", path.display())),
    }
}

/// Gravity of a row from optional gx, gy, gz columns (dataset.md: absent means head upright).
pub struct GravityCols(Option<[usize; 3]>);

impl GravityCols {
    /// The gx, gy, gz columns if all three are there.
    pub fn find(t: &Table) -> Self {
        let idx: Option<Vec<usize>> = ["gx", "gy", "gz"].iter().map(|n| t.header.iter().position(|h| h == n)).collect();
        GravityCols(idx.map(|v| [v[0], v[1], v[2]]))
    }

    /// The row's gravity, a unit vector.
    pub fn of(&self, path: &Path, line: usize, row: &[String]) -> std::result::Result<[f64; 3], String> {
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

/// Applies `f(inputs, line, whole row)` to each row of `t` (read from `input`), in order, and fills the named
/// output columns (appended if absent). A row that fails keeps empty outputs; the answer is each failed
/// row's error ("file:line: why"), in order. A table without rows is refused: nothing computed is not a
/// success.
pub fn map_rows(
    t: &mut Table,
    input: &Path,
    inputs: &[&str],
    outputs: &[&str],
    mut f: impl FnMut(&[f64], usize, &[String]) -> std::result::Result<Vec<f64>, String>,
) -> Result<Vec<String>> {
    let ic: Vec<usize> = inputs.iter().map(|n| t.col(input, n)).collect::<Result<_>>()?;
    let oc: Vec<usize> = outputs.iter().map(|n| t.out_col(n)).collect();
    if t.rows.is_empty() {
        return Err(EyeError::file(input, None, "no rows to compute (a header without data)"));
    }
    let mut failed = Vec::new();
    for (k, row) in t.rows.iter_mut().enumerate() {
        let line = k + 2;
        let vals: std::result::Result<Vec<f64>, String> =
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
                failed.push(e);
                for c in &oc {
                    row[*c].clear();
                }
            }
        }
    }
    Ok(failed)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table(rows: &[&[&str]]) -> Table {
        Table {
            header: ["x", "keep", "gx", "gy", "gz"].map(String::from).to_vec(),
            rows: rows.iter().map(|r| r.iter().map(|s| s.to_string()).collect()).collect(),
        }
    }

    #[test]
    fn map_rows_fills_outputs_and_names_each_failed_row_by_its_line() {
        let p = Path::new("in.csv");
        let mut t = table(&[&["1", "a", "0", "1", "0"], &["x", "b", "0", "1", "0"], &["3", "c", "0", "2", "0"]]);
        let g = GravityCols::find(&t);
        let failed = map_rows(&mut t, p, &["x"], &["y"], |v, line, row| {
            let gr = g.of(p, line, row)?;
            Ok(vec![2.0 * v[0] + gr[1]])
        })
        .unwrap();
        assert_eq!(t.header.last().unwrap(), "y");
        assert_eq!(t.rows.iter().map(|r| r[5].as_str()).collect::<Vec<_>>(), ["3", "", ""]);
        assert_eq!(t.rows[1][1], "b", "other columns pass through");
        assert_eq!(failed.len(), 2);
        assert!(failed[0].starts_with("in.csv:3: column x: \"x\" is not a number"), "{}", failed[0]);
        assert!(failed[1].starts_with("in.csv:4: columns gx, gy, gz") && failed[1].contains("length 2.0000"));
        // a missing column and a table without rows are refused whole
        assert!(map_rows(&mut t, p, &["z"], &["y"], |_, _, _| Ok(vec![]))
            .unwrap_err()
            .to_string()
            .contains(":1: missing column z"));
        assert!(map_rows(&mut table(&[]), p, &["x"], &["y"], |_, _, _| Ok(vec![])).is_err());
    }
}
