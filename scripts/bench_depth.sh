#!/usr/bin/env bash
# Issue 13's speed bar, as a benchmark (not a timed test): paced replays of the fixture at its recorded
# 25 fps, ROUNDS rounds, each running the network engine and SGBM back to back (order alternating) at
# the runtime's default resolution (or --resolution WxH given after the counts). Prints, per engine, the
# medians over rounds of the achieved fps, the end-to-end latency p50 and p99 (frame mid-exposure ->
# cloud published), the frames dropped (all rounds) and the disparity stage's p50, and the median of the
# paired ratio disparity(network) / disparity(SGBM) of the same round.
#   cargo build --release -p abvs && scripts/bench_depth.sh [ROUNDS=5] [FRAMES=125] [run flags]
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
ROUNDS=${1:-5}
FRAMES=${2:-125}
shift $(( $# < 2 ? $# : 2 ))
BIN=${ABVS:-target/release/abvs}
OUT=$(mktemp -d)
trap 'rm -rf "$OUT"' EXIT
echo "load average: $(cut -d' ' -f1-3 /proc/loadavg); $(nproc) cores; $BIN"
for i in $(seq 1 "$ROUNDS"); do
  if (( i % 2 )); then order=(onnx sgbm); else order=(sgbm onnx); fi
  for e in "${order[@]}"; do
    "$BIN" run --quiet --truth-stride 0 --frames "$FRAMES" --engine "$e" --service-prefix "abvs-bench-$$" "$@" \
      --stats-json "$OUT/$e-$i.json" >/dev/null 2>&1
  done
done
echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg)"
python3 - "$OUT" "$ROUNDS" <<'PY'
import json, statistics as st, sys
out, n = sys.argv[1], int(sys.argv[2])
load = lambda e: [json.load(open(f"{out}/{e}-{i}.json")) for i in range(1, n + 1)]
runs = {e: load(e) for e in ["onnx", "sgbm"]}
for e, vs in runs.items():
    med = lambda f: st.median(f(v) for v in vs)
    print(f"{vs[0]['engine']:16} {vs[0]['resolution'][0]}x{vs[0]['resolution'][1]}: "
          f"fps {med(lambda v: v['fps']):.1f}, end-to-end p50 {med(lambda v: v['latency_ms']['p50']):.1f} ms, "
          f"p99 {med(lambda v: v['latency_ms']['p99']):.1f} ms, dropped {sum(v['frames_dropped'] for v in vs)} "
          f"of {sum(v['frames_in'] for v in vs)}, disparity stage p50 {med(lambda v: v['stages']['disparity']['p50']):.1f} ms")
r = [a["stages"]["disparity"]["p50"] / b["stages"]["disparity"]["p50"] for a, b in zip(runs["onnx"], runs["sgbm"])]
print(f"disparity stage network / SGBM, paired by round: median {st.median(r):.3f} (min {min(r):.3f}, max {max(r):.3f})")
PY
