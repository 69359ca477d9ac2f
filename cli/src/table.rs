//! The row-by-row mapping of `kin` and `calib predict | ik` (`abvs_eye::table`) as a command ends it: each
//! failed row reported on stderr, the table written, non-zero exit if any row failed.
use abvs_eye::table::Table;
use std::path::Path;
use std::process::ExitCode;

/// Applies `f(inputs, line, whole row)` to each row of `t` (read from `input`) and fills the
/// named output columns; writes `out`.
pub fn map_rows(
    mut t: Table,
    input: &Path,
    out: &Path,
    inputs: &[&str],
    outputs: &[&str],
    f: impl FnMut(&[f64], usize, &[String]) -> Result<Vec<f64>, String>,
) -> anyhow::Result<ExitCode> {
    let failed = abvs_eye::table::map_rows(&mut t, input, inputs, outputs, f)?;
    for e in &failed {
        eprintln!("error: {e}");
    }
    t.write(out)?;
    if failed.is_empty() {
        eprintln!("wrote {} ({} rows)", out.display(), t.rows.len());
        Ok(ExitCode::SUCCESS)
    } else {
        let n = failed.len();
        eprintln!("{n} of {} rows failed; {} written with those rows' outputs empty", t.rows.len(), out.display());
        Ok(ExitCode::FAILURE)
    }
}
