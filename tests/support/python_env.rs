//! The Python environment of the tests that check the runtime's outputs from Python, shared by the test
//! binaries of several crates (`#[path]`-included: each crate sits one level under the repository).
#![allow(dead_code)]
use std::path::PathBuf;

/// The repository's root.
pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// `ABVS_PYTHON`, else `.deps/python/bin/python3` (scripts/setup.sh); a missing one fails the test by name.
pub fn python() -> PathBuf {
    let p =
        std::env::var_os("ABVS_PYTHON").map(PathBuf::from).unwrap_or_else(|| repo().join(".deps/python/bin/python3"));
    assert!(p.exists(), "{}: no Python environment; run scripts/setup.sh (or set ABVS_PYTHON)", p.display());
    p
}
