#!/usr/bin/env bash
# Issue 28's speed bars, as a benchmark (not a timed test): paced replays of the fixture at its recorded
# 25 fps, ROUNDS rounds, each running `abvs run` as the README runs it (no flags: the default engine, truth
# scoring on its side lane) and the same with `--engine sgbm` (OpenCV SGBM_3WAY, the same 2 threads) back to
# back, order alternating, at the runtime's default resolution (or the run flags given after the counts).
# Prints, per run, the medians over rounds of the achieved fps, the end-to-end latency p50 and p99 (frame
# exists, its last row exposed -> cloud published), the frames dropped (all rounds), the frames the truth scored, the
# disparity stage's p50, and the median of the paired ratio disparity(default) / disparity(SGBM_3WAY) of the
# same round; and CPU time per frame (all of it, and without the idle-priority side lanes).
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
  if (( i % 2 )); then order=(default sgbm); else order=(sgbm default); fi
  for e in "${order[@]}"; do
    if [[ $e == sgbm ]]; then flags=(--engine sgbm); else flags=(); fi
    "$BIN" run --quiet --frames "$FRAMES" ${flags[@]+"${flags[@]}"} --service-prefix "abvs-bench-$$" "$@" \
      --stats-json "$OUT/$e-$i.json" >/dev/null 2>&1
  done
done
echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg)"
python3 - "$OUT" "$ROUNDS" <<'PY'
import json, statistics as st, sys
out, n = sys.argv[1], int(sys.argv[2])
load = lambda e: [json.load(open(f"{out}/{e}-{i}.json")) for i in range(1, n + 1)]
runs = {e: load(e) for e in ["default", "sgbm"]}
for e, vs in runs.items():
    med = lambda f: st.median(f(v) for v in vs)
    lane = [v.get("truth_side_lane", {}) for v in vs]
    print(f"{e:8} {vs[0]['engine']:22} {vs[0]['resolution'][0]}x{vs[0]['resolution'][1]}: "
          f"fps {med(lambda v: v['fps']):.1f}, end-to-end p50 {med(lambda v: v['latency_ms']['p50']):.1f} ms, "
          f"p99 {med(lambda v: v['latency_ms']['p99']):.1f} ms, dropped {sum(v['frames_dropped'] for v in vs)} "
          f"of {sum(v['frames_in'] for v in vs)}, truth scored {sum(l.get('frames_consumed', 0) for l in lane)} "
          f"of {sum(l.get('frames_in', 0) for l in lane)}, "
          f"disparity stage p50 {med(lambda v: v['stages']['disparity']['p50']):.1f} ms, "
          f"abs_rel {med(lambda v: v.get('depth_error', {}).get('abs_rel', float('nan'))):.4f}")
# CPU per frame (the work, whatever queueing did to latency): all of it, and without the threads that run at
# idle priority on CPU time the pipeline leaves (the side lanes: the truth's scoring, the self-check)
side = lambda v: v["cpu"]["idle_priority_ms_per_frame"]
for e, vs in runs.items():
    med = lambda f: st.median(f(v) for v in vs)
    print(f"{e:8} CPU per frame {med(lambda v: v['cpu']['ms_per_frame']):.1f} ms, without the idle-priority side "
          f"lanes {med(lambda v: v['cpu']['ms_per_frame'] - side(v)):.1f} ms; disparity lane "
          f"{med(lambda v: v['cpu']['lanes_ms_per_frame']['disparity']):.1f} ms, cores busy "
          f"{med(lambda v: v['cpu']['cores_busy']):.2f} of {vs[0]['cpu']['cores']} "
          f"(at 25 fps {vs[0]['cpu']['cores']} cores have {vs[0]['cpu']['cores'] * 40} ms per frame)")
r = [a["stages"]["disparity"]["p50"] / b["stages"]["disparity"]["p50"] for a, b in zip(runs["default"], runs["sgbm"])]
print(f"disparity stage default / SGBM_3WAY, paired by round: median {st.median(r):.3f} (min {min(r):.3f}, max {max(r):.3f})")
PY
