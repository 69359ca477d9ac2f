#!/usr/bin/env bash
# Draws the README's picture (docs/fixture_output.png): the default run's first frame as `abvs run --dump`
# writes it (rectified left and right, depth, the cloud seen from above).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
out="$(mktemp -d)"
cargo run --release -q -p abvs -- run --lossless --dump "$out" > /dev/null
first="$(ls "$out"/frame_*.png | head -n1)"
cp "$first" docs/fixture_output.png
echo "wrote docs/fixture_output.png from $first"
rm -rf "$out"
