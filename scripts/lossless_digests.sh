#!/usr/bin/env bash
# Prints `abvs run --lossless` output digests for every engine at both shipped resolutions, one line
# each: a restructuring must leave every line unchanged (issue 43). Usage: scripts/lossless_digests.sh [ABVS]
set -euo pipefail
abvs="${1:-target/debug/abvs}"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
for engine in census-refine onnx sgbm fused; do
  for res in 640x480 320x240; do
    "$abvs" run --lossless --no-publish --quiet --engine "$engine" --resolution "$res" \
      --stats-json "$tmp/s.json" >/dev/null
    printf '%s %s %s\n' "$engine" "$res" \
      "$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["output_digest"])' "$tmp/s.json")"
  done
done
