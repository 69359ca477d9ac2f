#!/usr/bin/env bash
# The self-check's cost on the critical path: paced replays of the fixture (25 fps, default ONNX engine)
# without the self-check, with it at its default rate (every 5th frame) and on every frame, interleaved in
# rotating order ROUNDS times; prints each configuration's median end-to-end latency p50, the median of its
# ratio to the paired run without, and the stage p50s.
#   cargo build --release -p abvs && scripts/bench_self_check.sh [ROUNDS=12] [FRAMES=125] [extra abvs run flags]
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
ROUNDS=${1:-12}
FRAMES=${2:-125}
shift $(( $# < 2 ? $# : 2 ))
BIN=${ABVS:-target/release/abvs}
OUT=$(mktemp -d)
cfgs=(off default every1)
for i in $(seq 1 "$ROUNDS"); do
  for j in 0 1 2; do
    m=${cfgs[$(( (i + j) % 3 ))]}
    case $m in
      off) extra=() ;;
      default) extra=(--self-check) ;;
      every1) extra=(--self-check --self-check-every 1) ;;
    esac
    "$BIN" run --quiet --no-publish --truth-stride 0 --frames "$FRAMES" "${extra[@]}" "$@" \
      --stats-json "$OUT/$m-$i.json" >/dev/null 2>&1
  done
done
python3 - "$OUT" "$ROUNDS" <<'PY'
import json, statistics as st, sys
out, n = sys.argv[1], int(sys.argv[2])
load = lambda m: [json.load(open(f"{out}/{m}-{i}.json")) for i in range(1, n + 1)]
off = load("off")
for m in ["off", "default", "every1"]:
    vs = load(m)
    e = [v["latency_ms"]["p50"] for v in vs]
    r = [v["latency_ms"]["p50"] / o["latency_ms"]["p50"] for v, o in zip(vs, off)]
    line = (f"{m:8} end-to-end p50 median {st.median(e):6.2f} ms, paired ratio median {st.median(r):.3f}; stage p50 "
            + " ".join(f"{k} {st.median([v['stages'][k]['p50'] for v in vs]):.2f}" for k in ["rectify", "disparity", "output"]))
    if m != "off":
        sc = [v["self_check"] for v in vs]
        line += (f"; checked {st.median([s['frames'] for s in sc]):.0f} of {vs[0]['frames_published']},"
                 f" {st.median([s['check_cpu_ms']['p50'] for s in sc]):.1f} ms CPU a check")
    print(line)
PY
rm -rf "$OUT"
