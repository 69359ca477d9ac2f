#!/usr/bin/env bash
# End-to-end latency of two abvs builds on the same machine, e.g. before and after a change to the
# runtime's runner: paced replays of the fixture (25 fps, default ONNX engine, no publishing, no truth
# scoring), the two binaries interleaved in alternating order ROUNDS times; prints each one's median of the
# per-run end-to-end p50 / p99, the median of the paired p50 ratio (B / A) and the stage p50s.
#   scripts/bench_runner.sh BIN_A BIN_B [ROUNDS=15] [FRAMES=125] [extra abvs run flags]
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
A=$1
B=$2
ROUNDS=${3:-15}
FRAMES=${4:-125}
shift $(( $# < 4 ? $# : 4 ))
OUT=$(mktemp -d)
for i in $(seq 1 "$ROUNDS"); do
  if (( i % 2 )); then order=(a b); else order=(b a); fi
  for m in "${order[@]}"; do
    if [[ $m == a ]]; then bin=$A; else bin=$B; fi
    "$bin" run --quiet --no-publish --truth-stride 0 --frames "$FRAMES" "$@" \
      --stats-json "$OUT/$m-$i.json" >/dev/null 2>&1
  done
done
python3 - "$OUT" "$ROUNDS" "$A" "$B" <<'PY'
import json, statistics as st, sys
out, n, names = sys.argv[1], int(sys.argv[2]), {"a": sys.argv[3], "b": sys.argv[4]}
load = lambda m: [json.load(open(f"{out}/{m}-{i}.json")) for i in range(1, n + 1)]
a, b = load("a"), load("b")
for m, vs in [("a", a), ("b", b)]:
    e50 = [v["latency_ms"]["p50"] for v in vs]
    e99 = [v["latency_ms"]["p99"] for v in vs]
    print(f"{m} {names[m]}: end-to-end p50 median {st.median(e50):.2f} ms (runs {min(e50):.2f}..{max(e50):.2f}), "
          f"p99 median {st.median(e99):.2f} ms; stage p50 "
          + " ".join(f"{k} {st.median([v['stages'][k]['p50'] for v in vs]):.2f}" for k in ["source", "rectify", "disparity", "output"])
          + f"; published {st.median([v['frames_published'] for v in vs]):.0f}, dropped {sum(v['frames_dropped'] for v in vs)}")
r = [y["latency_ms"]["p50"] / x["latency_ms"]["p50"] for x, y in zip(a, b)]
print(f"paired p50 ratio b/a: median {st.median(r):.3f} (runs {min(r):.3f}..{max(r):.3f}), {n} pairs")
PY
rm -rf "$OUT"
