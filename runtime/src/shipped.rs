//! The resources shipped in the checkout (the fixture session, configurations), found from the running
//! program or from the source tree it was built from. (The disparity models: `abvs_disparity::manifest`.)
use std::path::{Path, PathBuf};

/// The checkout's `rel` (e.g. `fixtures/session`, `models/hitnet`): next to the executable's checkout (up to four
/// directories above it: `target/<profile>/examples/`), else in the source tree this crate was built from.
pub fn shipped(rel: &str) -> PathBuf {
    let mut candidates = Vec::new();
    if let Ok(exe) = std::env::current_exe() {
        for a in exe.ancestors().skip(1).take(4) {
            candidates.push(a.join(rel));
        }
    }
    candidates.push(Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(rel));
    candidates.iter().find(|p| p.exists()).cloned().unwrap_or_else(|| candidates.pop().expect("one candidate"))
}
