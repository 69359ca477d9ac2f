//! Output paths checked before any work: a run of minutes (a soak, a fit) must not end by losing
//! its results to a missing or read-only directory. Each check names the flag or configuration field.
use std::path::Path;

use abvs_runtime_core::error::{Result, RuntimeError};

fn refuse<T>(field: &str, p: &Path, msg: String) -> Result<T> {
    Err(RuntimeError::Output { field: field.to_string(), path: p.to_path_buf(), msg })
}

fn writable_dir(p: &Path) -> bool {
    use std::os::unix::ffi::OsStrExt;
    let Ok(c) = std::ffi::CString::new(p.as_os_str().as_bytes()) else { return false };
    // SAFETY: a valid NUL-terminated path; access() only reads it.
    unsafe { libc::access(c.as_ptr(), libc::W_OK | libc::X_OK) == 0 }
}

/// The directory a relative file name lives in ("" is the working directory).
fn parent_of(p: &Path) -> &Path {
    match p.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    }
}

/// A file the command will write: its directory exists and is writable, and the path is not a directory.
pub fn check_file_writable(flag: &str, p: &Path) -> Result<()> {
    if p.is_dir() {
        return refuse(flag, p, "is a directory, expected a file name".into());
    }
    let d = parent_of(p);
    if !d.is_dir() {
        return refuse(flag, p, format!("directory {} does not exist", d.display()));
    }
    if !writable_dir(d) {
        return refuse(flag, p, format!("directory {} is not writable", d.display()));
    }
    Ok(())
}

/// A directory the command will create (or write into): not a file, and its nearest existing
/// ancestor is a writable directory.
pub fn check_dir_creatable(flag: &str, p: &Path) -> Result<()> {
    if p.exists() {
        if !p.is_dir() {
            return refuse(flag, p, "exists and is not a directory".into());
        }
        if !writable_dir(p) {
            return refuse(flag, p, "directory is not writable".into());
        }
        return Ok(());
    }
    let mut a = parent_of(p);
    while !a.exists() {
        a = parent_of(a);
    }
    if !a.is_dir() || !writable_dir(a) {
        return refuse(flag, p, format!("cannot be created ({} is not a writable directory)", a.display()));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn missing_directories_and_files_in_the_way() {
        let d = tempfile::tempdir().unwrap();
        check_file_writable("--x", &d.path().join("a.json")).unwrap();
        let e = check_file_writable("--stats-json", &d.path().join("missing/a.json")).unwrap_err().to_string();
        assert!(e.contains("--stats-json") && e.contains("does not exist"), "{e}");
        assert!(check_file_writable("--x", d.path()).is_err());
        check_dir_creatable("--dump", &d.path().join("new/deeper")).unwrap();
        std::fs::write(d.path().join("f"), "").unwrap();
        assert!(check_dir_creatable("--dump", &d.path().join("f")).is_err());
        assert!(check_dir_creatable("--dump", &d.path().join("f/sub")).is_err());
        check_file_writable("--x", Path::new("relative.json")).unwrap();
    }
}
