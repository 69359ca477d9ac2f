#!/usr/bin/env bash
# What census-refine's confidence and validity mask add to the disparity stage (issue 41: at most +10 %):
# the runtime's default engine at 640x480 on a real pair, scored and masked against the same engine without
# its confidence, interleaved frame by frame in ROUNDS rounds of REPS frames per arm; prints each round's
# ratio of the arms' median frame times and the median of the ratios (disparity/examples/confidence_cost.rs).
#   scripts/bench_confidence_cost.sh [ROUNDS=9] [REPS=10] [LEFT RIGHT (default: Aloe, opencv-doc)]
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
data=/usr/share/doc/opencv-doc/examples/data
cargo build --release -q -p abvs-disparity --example confidence_cost
target/release/examples/confidence_cost "${3:-$data/aloeL.jpg}" "${4:-$data/aloeR.jpg}" "${1:-9}" "${2:-10}"
