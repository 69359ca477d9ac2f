#!/usr/bin/env bash
# Regenerates the embedded default session fixtures/session/: seed 1, 50 frames at 800x600, eyes that move
# like real ones (rolling-shutter readout 30 ms, exposure 4 ms, pursuit up to 60 deg/s, saccades up to
# 1561 deg/s). The frames are then recompressed losslessly by optipng (the same pixels; noisy images
# compress best with Huffman-only deflate, which the image crate's encoder does not offer): the fixture
# stays under its former size. The measured home stereo calibration (calib/stereo.yaml, from rendered
# AprilGrid pairs: README "The runtime") and the eyes' calibrated FK (calib/eye0, eye1: same units, same
# calibration datasets) do not depend on the motion and are kept as committed.
#   cargo build --release -p abvs && scripts/regenerate_fixture.sh
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
BIN=${ABVS:-target/release/abvs}
command -v optipng >/dev/null || { echo "optipng not found: apt-get install optipng" >&2; exit 1; }
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
"$BIN" sim session --out "$tmp/s" --seed 1 --readout-ms 30 --exposure-ms 4 --pursuit-deg-s 60
ls "$tmp"/s/frames/*.png | xargs -P "$(nproc)" -n 8 optipng -quiet -o2
rm -rf "$tmp/s/calib"
for f in frames frames.csv encoders.csv session.toml truth; do
  rm -rf "fixtures/session/$f"
  cp -r "$tmp/s/$f" "fixtures/session/$f"
done
du -sb fixtures/session
