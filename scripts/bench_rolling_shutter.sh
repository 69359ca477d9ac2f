#!/usr/bin/env bash
# What the per-row (rolling-shutter) correction costs: paced replays of the fixture at its recorded 25 fps
# and the runtime's default resolution, ROUNDS rounds, each running the correction on and off back to back
# (order alternating). Prints per setting the medians over rounds of the end-to-end latency p50 / p99 and
# the rectify lane's p50 (where the per-row maps are built), CPU per frame (all, and the rectify lane's), and
# the paired ratios on / off.
#   cargo build --release -p abvs && scripts/bench_rolling_shutter.sh [ROUNDS=5] [FRAMES=125] [run flags]
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
  if (( i % 2 )); then order=(on off); else order=(off on); fi
  for rs in "${order[@]}"; do
    "$BIN" run --quiet --truth-stride 0 --frames "$FRAMES" --rolling-shutter "$rs" --service-prefix "abvs-bench-$$" "$@" \
      --stats-json "$OUT/$rs-$i.json" >/dev/null 2>&1
  done
done
echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg)"
python3 - "$OUT" "$ROUNDS" <<'PY'
import json, statistics as st, sys
out, n = sys.argv[1], int(sys.argv[2])
runs = {rs: [json.load(open(f"{out}/{rs}-{i}.json")) for i in range(1, n + 1)] for rs in ["on", "off"]}
for rs, vs in runs.items():
    med = lambda f: st.median(f(v) for v in vs)
    print(f"rolling shutter {rs:3} ({vs[0]['engine']}, {vs[0]['resolution'][0]}x{vs[0]['resolution'][1]}, readout "
          f"{vs[0]['motion']['readout_ms']} ms): fps {med(lambda v: v['fps']):.1f}, end-to-end p50 "
          f"{med(lambda v: v['latency_ms']['p50']):.1f} ms, p99 {med(lambda v: v['latency_ms']['p99']):.1f} ms, "
          f"rectify p50 {med(lambda v: v['stages']['rectify']['p50']):.2f} ms, CPU per frame "
          f"{med(lambda v: v['cpu']['ms_per_frame']):.1f} ms (rectify lane {med(lambda v: v['cpu']['lanes_ms_per_frame']['rectify']):.2f}), "
          f"dropped {sum(v['frames_dropped'] for v in vs)} of {sum(v['frames_in'] for v in vs)}")
for what, f in [("end-to-end p50", lambda v: v["latency_ms"]["p50"]), ("rectify p50", lambda v: v["stages"]["rectify"]["p50"]),
                ("CPU per frame", lambda v: v["cpu"]["ms_per_frame"]),
                ("rectify lane CPU per frame", lambda v: v["cpu"]["lanes_ms_per_frame"]["rectify"])]:
    r = [f(a) / f(b) for a, b in zip(runs["on"], runs["off"])]
    print(f"{what} on / off, paired by round: median {st.median(r):.3f} (min {min(r):.3f}, max {max(r):.3f})")
PY
