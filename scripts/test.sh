#!/usr/bin/env bash
# Installs what abvs needs (scripts/setup.sh), then builds everything (benches included) and
# runs every test of the workspace.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
./scripts/setup.sh
cargo build --workspace --all-targets
cargo test --workspace
