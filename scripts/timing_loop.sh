#!/usr/bin/env bash
# The eyes' timing measured from the runtime's own images (issue 23), closing the loop on a rendered session:
#   1. render a session whose eyes pursue (up to 90 deg/s) and verge, with a rolling-shutter readout and an
#      encoder time offset;
#   2. replay it with the true timing (the reference) and with the timing set to zero, self-check on every frame;
#   3. `abvs calib self-check` estimates the timing from the zero run's log, re-runs the replay with its
#      estimate and fits again while the correction is large (up to 3 rounds: the model is first order), and
#      writes the result into session.toml; the replay repeated with no timing flags reads it from there;
#   4. prints the estimates and, per run, the self-check's rotation error during motion and the depth error
#      of the fast-pursuit band [30, 100) deg/s; error_by_speed.png (the zero run and each round) in OUT/estimate.
# usage: scripts/timing_loop.sh [OUT] [SEED] [OFFSET_MS] [READOUT_MS] [FRAMES]   (release build; about 2 minutes)
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
OUT=${1:-target/timing-loop}
SEED=${2:-21}
OFFSET=${3:-2.5}
READOUT=${4:-25}
FRAMES=${5:-100}
cargo build --release -q -p abvs
BIN=target/release/abvs
rm -rf "$OUT" && mkdir -p "$OUT"
S="$OUT/session"
"$BIN" sim session --out "$S" --seed "$SEED" --frames "$FRAMES" --width 640 --height 480 --supersample 1 \
  --readout-ms "$READOUT" --exposure-ms 4 --pursuit-deg-s 90 --time-offset-ms "$OFFSET" >/dev/null
run() { # name, extra flags
  "$BIN" run --quiet --no-publish --lossless --engine sgbm --truth-stride 4 --session "$S" \
    --self-check-every 1 --self-check-log "$OUT/$1.csv" --stats-json "$OUT/$1.json" "${@:2}" 2>/dev/null
}
run true --time-offset-ms "$OFFSET" --readout-ms "$READOUT"
run zero --time-offset-ms 0 --readout-ms 0
"$BIN" calib self-check --log "$OUT/true.csv" --out "$OUT/estimate-true" --rounds 0 | grep timing
# from the zero run: the fit, then up to three rounds of the replay re-run with the estimate (--rounds)
"$BIN" calib self-check --log "$OUT/zero.csv" --out "$OUT/estimate" --write-session "$S" | grep timing
run after   # no timing flags: the runtime reads the estimate from session.toml
python3 - "$OUT" "$OFFSET" "$READOUT" <<'PY'
import csv, json, statistics, sys
out, offset, readout = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
def motion_error(name):
    rows = [r for r in csv.DictReader(open(f"{out}/{name}.csv")) if r["rot_x_deg"]]
    fast = [sum(float(r[k]) ** 2 for k in ("rot_x_deg", "rot_y_deg", "rot_z_deg")) ** 0.5
            for r in rows if max(float(r["speed_l_deg_s"]), float(r["speed_r_deg_s"])) >= 30]
    return statistics.median(fast), len(fast)
def band(name):
    s = json.load(open(f"{out}/{name}.json"))
    b = next(b for b in s["depth_error_by_speed"] if b["deg_s"][0] == 30)
    return b["abs_rel"], b["point_mm_p50"], b["frames"]
t = json.load(open(f"{out}/estimate-true/summary.json"))["timing"]
print(f"from the true-timing run: offset {t['encoder_time_offset_ms']['value']:.2f} +- {t['encoder_time_offset_ms']['sigma']:.2f} ms, "
      f"readout {t['readout_ms']['value']:.2f} +- {t['readout_ms']['sigma']:.2f} ms (true {offset}, {readout})")
for k, r in enumerate(json.load(open(f"{out}/estimate/summary.json"))["timing"]["rounds"]):
    print(f"round {k}: offset {r['encoder_time_offset_ms']['value']:.2f} +- {r['encoder_time_offset_ms']['sigma']:.2f} ms, "
          f"readout {r['readout_ms']['value']:.2f} +- {r['readout_ms']['sigma']:.2f} ms, held-out improvement {100 * r['heldout_improvement']:.0f} %")
print("| run | self-check |rotation error| at >= 30 deg/s, median (deg) | [30,100) abs_rel | [30,100) point_mm_p50 |")
print("|---|---|---|---|")
for name in ("true", "zero", "after"):
    e, n = motion_error(name)
    a, p, f = band(name)
    print(f"| {name} | {e:.4f} ({n} frames) | {a:.4f} | {p:.1f} ({f} frames) |")
PY
