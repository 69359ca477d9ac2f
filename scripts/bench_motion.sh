#!/usr/bin/env bash
# Issue 27's table: depth error by eye speed on a rendered session whose eyes move while they expose
# (readout 30 ms, exposure 4 ms, pursuit up to 90 deg/s, saccades), replayed with the per-row correction
# on and off, and the same motion rendered with a global shutter and no blur. Lossless replays at the
# runtime's defaults (640x480, default engine, calibrated FK); prints a markdown table.
# READOUT_MS, EXPOSURE_MS and PURSUIT_DEG_S (defaults 30, 4, 90) render other timings.
#   cargo build --release -p abvs && scripts/bench_motion.sh [SEED=11] [run flags]
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
SEED=${1:-11}
shift $(( $# < 1 ? $# : 1 ))
BIN=${ABVS:-target/release/abvs}
OUT=${BENCH_MOTION_DIR:-$(mktemp -d)}
READOUT=${READOUT_MS:-30}
EXPOSURE=${EXPOSURE_MS:-4}
PURSUIT=${PURSUIT_DEG_S:-90}
mkdir -p "$OUT"
for s in rolling global; do
  if [ ! -f "$OUT/$s/session.toml" ]; then
    if [ "$s" = rolling ]; then timing=(--readout-ms "$READOUT" --exposure-ms "$EXPOSURE"); else timing=(--readout-ms 0 --exposure-ms 0); fi
    echo "rendering $OUT/$s (seed $SEED)..." >&2
    "$BIN" sim session --out "$OUT/$s" --seed "$SEED" --pursuit-deg-s "$PURSUIT" "${timing[@]}" >/dev/null
  fi
done
run() { "$BIN" run --quiet --no-publish --lossless --session "$OUT/$1" --rolling-shutter "$2" "${@:3}" --stats-json "$OUT/$1-$2.json"; }
run rolling on "$@"
run rolling off "$@"
run global on "$@"
python3 - "$OUT" "$READOUT" "$EXPOSURE" <<'PY'
import json, sys
out = sys.argv[1]
timing = f"rolling shutter {sys.argv[2]} ms, exposure {sys.argv[3]} ms"
runs = [(f"{timing}, correction on", "rolling-on"),
        (f"{timing}, correction off", "rolling-off"),
        ("global shutter, no blur", "global-on")]
data = {k: json.load(open(f"{out}/{k}.json")) for _, k in runs}
first = data["rolling-on"]
print(f"engine {first['engine']} at {first['resolution'][0]}x{first['resolution'][1]}, fk {first['fk']}, "
      f"gate {first['motion']['gate_blur_px']} px")
print()
print("| session, correction | " + " | ".join(
    f"[{b['deg_s'][0]:g}, {'inf' if b['deg_s'][1] is None else format(b['deg_s'][1], 'g')})"
    for b in first["depth_error_by_speed"]) + " |")
print("| --- |" + " ---: |" * len(first["depth_error_by_speed"]))
for name, k in runs:
    cells = []
    for b in data[k]["depth_error_by_speed"]:
        if b["frames"] == 0:
            cells.append(f"- ({b['gated']} gated)")
        else:
            cells.append(f"{100 * b['abs_rel']:.2f} % / {b['point_mm_p50']:.1f} mm ({b['frames']}+{b['gated']}g)")
    print(f"| {name} | " + " | ".join(cells) + " |")
band = lambda k: next(b for b in data[k]["depth_error_by_speed"] if b["deg_s"][0] == 30)
on, off, gs = band("rolling-on"), band("rolling-off"), band("global-on")
print()
print(f"[30, 100) deg/s: corrected / global shutter: abs_rel {on['abs_rel'] / gs['abs_rel']:.2f}x, "
      f"point p50 {on['point_mm_p50'] / gs['point_mm_p50']:.2f}x; uncorrected / corrected point p50 "
      f"{off['point_mm_p50'] / on['point_mm_p50']:.2f}x")
PY
