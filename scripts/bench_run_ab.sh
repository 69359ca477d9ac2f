#!/usr/bin/env bash
# Two abvs binaries' real time, interleaved: ROUNDS rounds of `abvs run --frames FRAMES [ARGS...]` (the
# fixture, paced at 25 fps, frames dropped under overload) with binary A, then B. Prints per run the frames in,
# published and dropped, the fps, the frames the fovea matched and shed, and the CPU per frame (ms); then
# each binary's totals. Build the other binary first, e.g. `git stash; cargo build --release -p abvs; cp
# target/release/abvs /tmp/abvs-before; git stash pop; cargo build --release -p abvs`.
#   scripts/bench_run_ab.sh A B [ROUNDS=8] [FRAMES=50] [ARGS...]
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
[ $# -ge 2 ] || { sed -n 2,7p "$0"; exit 2; }
a=$1 b=$2 rounds=${3:-8} frames=${4:-50}
shift $(( $# < 4 ? $# : 4 ))
export ORT_DYLIB_PATH="${ORT_DYLIB_PATH:-$PWD/.deps/onnxruntime/libonnxruntime.so}"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
for r in $(seq 1 "$rounds"); do
  for arm in A B; do
    bin=$a; [ $arm = B ] && bin=$b
    "$bin" run --frames "$frames" --stats-json "$tmp/s.json" "$@" >/dev/null 2>"$tmp/err" || { cat "$tmp/err" >&2; exit 1; }
    python3 - "$tmp/s.json" "$arm" "$r" >>"$tmp/rows" <<'PY'
import json, sys
j = json.load(open(sys.argv[1])); f = j.get("fovea") or {}
print(sys.argv[2], sys.argv[3], j["frames_in"], j["frames_published"], j["frames_dropped"], round(j["fps"], 1),
      f.get("frames", "-"), f.get("shed_behind", "-"), round(j["cpu"]["ms_per_frame"], 1))
PY
    tail -1 "$tmp/rows"
  done
done
python3 - "$tmp/rows" "$a" "$b" <<'PY'
import statistics, sys
rows = [l.split() for l in open(sys.argv[1])]
for arm, name in (("A", sys.argv[2]), ("B", sys.argv[3])):
    r = [x for x in rows if x[0] == arm]
    dropped = [int(x[4]) for x in r]
    shed = sum(int(x[7]) for x in r if x[7] != "-")
    print(f"{arm} {name}: dropped {sum(dropped)} of {sum(int(x[2]) for x in r)}, runs with 0 dropped "
          f"{sum(d == 0 for d in dropped)} of {len(r)}, fovea shed {shed}, "
          f"CPU per frame median {statistics.median(float(x[8]) for x in r):.1f} ms")
PY
