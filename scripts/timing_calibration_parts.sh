#!/usr/bin/env bash
# Which part of the fixture's measured home stereo calibration moves the timing fit (issue 37): the fixture's
# images replayed with the true timing applied (the FK models' offsets, the session's 30 ms readout) and
# rectified with the true calibration, the measured one, and hybrids of the two (the measured intrinsics with the
# true R and T; the true intrinsics with the measured R and T, with the measured T alone, with the measured R
# alone), then `abvs calib self-check --rounds 0` on each log. Extra OpenCV stereo YAML files given as arguments
# (e.g. from `abvs sim stereo-session` + `abvs calib stereo`) are replayed the same way.
# ROUNDS=3 replays with zero timing applied instead and lets the fit refine it in that many rounds (the loop
# `cli/tests/timing.rs` the_fixture asserts on the shipped calibration).
#   cargo build --release -p abvs && [ROUNDS=3] scripts/timing_calibration_parts.sh [RESOLUTION=640x480] [more.yaml ...]
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
BIN=${ABVS:-target/release/abvs}
RES=${1:-640x480}
ROUNDS=${ROUNDS:-0}
START=()
if (( ROUNDS > 0 )); then START=(--time-offset-ms 0 --readout-ms 0); fi
shift $(( $# > 0 ? 1 : 0 ))
OUT=$(mktemp -d)
trap 'rm -rf "$OUT"' EXIT
cp -r fixtures/session "$OUT/fx"
python3 - fixtures/session/truth/stereo.yaml fixtures/session/calib/stereo.yaml "$OUT/fx/truth" <<'PY'
import sys
truth, measured, out = (open(sys.argv[1]).read(), open(sys.argv[2]).read(), sys.argv[3])
def parts(s):
    # the intrinsics (left:, right:), then R, then T and what follows (rms)
    i, j = s.index("\nR: !!opencv-matrix"), s.index("\nT: !!opencv-matrix")
    return s[:i], s[i:j], s[j:]
(ti, tr, tt), (mi, mr, mt) = parts(truth), parts(measured)
for name, text in {"p_mi": mi + tr + tt, "p_mRT": ti + mr + mt, "p_mT": ti + tr + mt, "p_mR": ti + mr + tt}.items():
    open(f"{out}/{name}.yaml", "w").write(text)
PY
cases=("true:truth/stereo.yaml" "measured:calib/stereo.yaml" "measured intrinsics:truth/p_mi.yaml"
       "measured R and T:truth/p_mRT.yaml" "measured T:truth/p_mT.yaml" "measured R:truth/p_mR.yaml")
for f in "$@"; do
  cp "$f" "$OUT/fx/truth/extra_$(basename "$f")"
  cases+=("$f:truth/extra_$(basename "$f")")
done
printf '%-40s %s\n' "stereo calibration ($RES, $([ "$ROUNDS" = 0 ] && echo true timing || echo "zero timing, $ROUNDS rounds"))" "offset left / right (ms), readout (ms); true 3.58 / 3.40, 30"
for c in "${cases[@]}"; do
  name=${c%%:*}; file=${c#*:}
  sed -i "s#^stereo = .*#stereo = \"$file\"#" "$OUT/fx/session.toml"
  "$BIN" run --quiet --no-publish --lossless --engine sgbm --truth-stride 0 --self-check-every 1 --resolution "$RES" \
    "${START[@]}" --session "$OUT/fx" --self-check-log "$OUT/log.csv" >/dev/null 2>&1
  rm -rf "$OUT/e"
  "$BIN" calib self-check --log "$OUT/log.csv" --out "$OUT/e" --rounds "$ROUNDS" >/dev/null
  python3 - "$OUT/e/summary.json" "$name" <<'PY'
import json, sys
t = json.load(open(sys.argv[1]))["timing"]
o = t["encoder_time_offset_ms"]
print(f"{sys.argv[2]:40s} {o['left']['value']:.2f} / {o['right']['value']:.2f} ± {o['left']['sigma']:.2f}, "
      f"{t['readout_ms']['value']:.2f} ± {t['readout_ms']['sigma']:.2f}")
PY
done
