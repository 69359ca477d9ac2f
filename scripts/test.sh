#!/usr/bin/env bash
# Installs what abvs needs (scripts/setup.sh), checks formatting, then builds and runs every test of the
# workspace (tests and examples; benches are built only by `cargo bench`) with clippy's lints, every
# warning an error. The rerun logging test is not run here: its feature's build (rerun and ~400 crates, and
# the workspace's dependencies again under other features) took 16 of a clean CI's 43 minutes on 2 cores,
# over the 40 the project allows. Run it by hand: `cargo test -p abvs --features rerun --test rerun`.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
./scripts/setup.sh
cargo fmt --all -- --check
# every package of the lock file, for every platform: tests/tests/layers.rs runs `cargo metadata --offline`,
# which reads them all (a fresh machine's build downloads only this platform's)
cargo fetch --locked
# Lints (the workspace's [workspace.lints] and clippy.toml) in the same build as the tests: clippy-driver
# compiles the workspace's own crates and lints them, rustc the dependencies, once. A separate
# `cargo clippy --workspace --all-targets -- -D warnings` type-checks the ~600 dependencies a second time:
# 7 of a clean CI's 40 minutes on 2 cores. (That command still works by hand, benches included.)
RUSTC_WORKSPACE_WRAPPER="$(rustup which clippy-driver 2>/dev/null || command -v clippy-driver)" || {
  echo "clippy-driver not found: rustup component add clippy" >&2
  exit 1
}
export RUSTC_WORKSPACE_WRAPPER
export CLIPPY_ARGS="-D__CLIPPY_HACKERY__warnings__CLIPPY_HACKERY__"
cargo test --workspace
# Not here: rustdoc's lints (scripts/doc_check.sh), which type-check every dependency a second time: 3.7 of a
# clean CI's 57 minutes on this 2-core VM on 2026-11-28, when the build alone took 36.
