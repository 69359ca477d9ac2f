//! SHA-256 of model files: manifests record it, loaders check it, so a damaged or swapped network
//! is refused instead of silently changing what the robot computes.
use crate::error::{FkError, Result};
use sha2::{Digest, Sha256};
use std::path::Path;

/// Hex SHA-256 of a file's bytes.
pub fn sha256_file(path: &Path) -> Result<String> {
    let bytes = std::fs::read(path).map_err(|e| FkError::io(path, e))?;
    Ok(Sha256::digest(&bytes).iter().map(|b| format!("{b:02x}")).collect())
}

/// Refuses a file whose SHA-256 is not the one its manifest records (naming the file, the
/// manifest and both hashes).
pub fn verify_sha256(path: &Path, manifest: &Path, expected: &str) -> Result<()> {
    let actual = sha256_file(path)?;
    if !actual.eq_ignore_ascii_case(expected.trim()) {
        return Err(FkError::model(
            path,
            format!(
                "SHA-256 {actual} differs from {expected} recorded in {}: the file was changed or damaged after \
                 the model was written",
                manifest.display()
            ),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_digest_and_mismatch() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("f");
        std::fs::write(&p, b"abc").unwrap();
        let h = sha256_file(&p).unwrap();
        assert_eq!(h, "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
        verify_sha256(&p, Path::new("m.json"), &h).unwrap();
        let e = verify_sha256(&p, Path::new("m.json"), &"0".repeat(64)).unwrap_err().to_string();
        assert!(e.contains(&h) && e.contains("m.json"), "{e}");
    }
}
