#!/usr/bin/env bash
# Installs what abvs needs (scripts/setup.sh), checks formatting and lints (clippy, -D warnings),
# then builds and runs every test of the workspace (tests and examples; benches are built only by
# `cargo bench`), then the rerun logging test once with its cargo feature.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
./scripts/setup.sh
cargo fmt --all -- --check
# Lints: clippy with every warning an error (the workspace's [workspace.lints] and clippy.toml).
cargo clippy --workspace --all-targets -- -D warnings
cargo test --workspace
# rerun (a 400-crate dependency) is behind the `rerun` feature: built and tested once here.
cargo test -p abvs --features rerun --test rerun
