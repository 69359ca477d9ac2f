#!/usr/bin/env bash
# rustdoc of the library crates, every warning an error (a broken link, a link to a private item): the
# dependencies are only type-checked for it, the workspace's crates documented. Run it by hand before a change
# to doc comments lands; CI leaves it out for time (scripts/test.sh): about 4 minutes on a clean clone.
#   scripts/doc_check.sh
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
RUSTDOCFLAGS="-D warnings" cargo doc --no-deps --workspace --exclude abvs --exclude abvs-tests
