#!/usr/bin/env bash
# Issue 38's real-time bar: `abvs run` replaying a 1600x1200 session, paced at the session's 25 fps, with the
# fovea on (the default) and off (`--fovea off`, same binary), in alternating order, ROUNDS times each.
# Prints per arm the frames published and dropped, end-to-end latency p50, and the runtime's own CPU
# accounting (stats JSON `cpu`): the whole process per frame, the fovea's lane, OpenCV's workers (the fovea's
# SGBM runs there too) and the fovea's share of the process (its lane plus the workers' increase over the
# paired run without it).
#   abvs sim session --out S --seed 7 --frames 100 --width 1600 --height 1200
#   scripts/bench_fovea_realtime.sh [ABVS=target/release/abvs] [SESSION] [ROUNDS=3] [extra abvs run flags]
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
ABVS=${1:-target/release/abvs}
SESSION=${2:?a 1600x1200 session directory}
ROUNDS=${3:-3}
shift $(( $# < 3 ? $# : 3 ))
OUT=$(mktemp -d)
trap 'rm -rf "$OUT"' EXIT
for i in $(seq 1 "$ROUNDS"); do
  # alternate which arm runs first: drift in the machine's load falls on both
  if (( i % 2 )); then arms=(on off); else arms=(off on); fi
  for arm in "${arms[@]}"; do
    extra=()
    [[ $arm == off ]] && extra+=(--fovea off)
    "$ABVS" run --quiet --session "$SESSION" --service-prefix "abvs-bench-fovea-$$-$i-$arm" "${extra[@]}" "$@" \
      --stats-json "$OUT/$arm-$i.json" >/dev/null 2>&1
  done
done
python3 - "$OUT" "$ROUNDS" <<'PY'
import json, statistics as st, sys
out, n = sys.argv[1], int(sys.argv[2])
load = lambda arm: [json.load(open(f"{out}/{arm}-{i}.json")) for i in range(1, n + 1)]
on, off = load("on"), load("off")
cpu = lambda v: v["cpu"]["ms_per_frame"]
workers = lambda v: v["cpu"]["other_threads_by_name_ms_per_frame"].get("workers", 0.0)
print("arm  round  in  published  dropped  e2e p50 (ms)  CPU/frame (ms)  fovea lane (ms)  workers (ms)")
for arm, runs in (("on", on), ("off", off)):
    for i, v in enumerate(runs, 1):
        lane = v["cpu"]["lanes_ms_per_frame"].get("fovea", 0.0)
        print(f"{arm:4} {i:5} {v['frames_in']:4} {v['frames_published']:10} {v['frames_dropped']:8} "
              f"{v['latency_ms']['p50']:13.2f} {cpu(v):15.1f} {lane:16.2f} {workers(v):13.2f}")
share = [(a["cpu"]["lanes_ms_per_frame"]["fovea"] + max(workers(a) - workers(b), 0.0)) / cpu(a) for a, b in zip(on, off)]
print(f"median over {n} rounds: on: dropped {st.median(v['frames_dropped'] for v in on)} of "
      f"{on[0]['frames_in']}, e2e p50 {st.median(v['latency_ms']['p50'] for v in on):.2f} ms, CPU "
      f"{st.median(cpu(v) for v in on):.1f} ms/frame; off: dropped {st.median(v['frames_dropped'] for v in off)}, "
      f"e2e p50 {st.median(v['latency_ms']['p50'] for v in off):.2f} ms, CPU {st.median(cpu(v) for v in off):.1f} ms/frame")
print(f"the fovea's share of the process's CPU (its lane + the workers' increase, paired): median {st.median(share):.3f}")
PY
