//! The binding specification travels with the repository (docs/spec), so a clone alone carries
//! it; it must stay identical to the shared original (../shared/spec) wherever that exists.
use std::path::Path;

const FILES: [&str; 3] = ["conventions.md", "dataset.md", "effects.md"];

#[test]
fn docs_spec_is_the_shared_spec() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let shared = root.join("../shared/spec");
    for f in FILES {
        let ours = std::fs::read(root.join("docs/spec").join(f)).unwrap_or_else(|e| panic!("docs/spec/{f}: {e}"));
        assert!(ours.len() > 500, "docs/spec/{f} is nearly empty");
        // A clean clone (CI) has no ../shared: the copy is then the only spec, checked above.
        if shared.is_dir() {
            let theirs = std::fs::read(shared.join(f)).unwrap_or_else(|e| panic!("shared/spec/{f}: {e}"));
            assert!(ours == theirs, "docs/spec/{f} differs from ../shared/spec/{f}: copy it again");
        }
    }
}
