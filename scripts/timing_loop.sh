#!/usr/bin/env bash
# The eyes' timing measured from the runtime's own images (issue 23), closing the loop on a rendered session:
#   1. render a session whose eyes pursue (up to 90 deg/s) and verge, with a rolling-shutter readout and an
#      encoder time offset;
#   2. replay it with the true timing (the reference) and with the timing set to zero, self-check on every frame;
#   3. `abvs calib self-check` estimates the timing from the zero run's log and writes it into session.toml;
#      the replay repeated with it (no timing flags: the runtime reads the session) and estimated again,
#      three rounds (the model is first order: far from the truth it only points the way);
#   4. prints the estimates and, per run, the self-check's rotation error during motion and the depth error
#      of the fast-pursuit band [30, 100) deg/s; error_by_speed.png (each round against the one before) in OUT/estimate-K.
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
"$BIN" calib self-check --log "$OUT/true.csv" --out "$OUT/estimate-true" | grep timing
"$BIN" calib self-check --log "$OUT/zero.csv" --out "$OUT/estimate-1" --write-session "$S" | grep timing
prev=zero
for k in 1 2 3; do
  run "round-$k"
  "$BIN" calib self-check --log "$OUT/round-$k.csv" --out "$OUT/estimate-$((k + 1))" --before "$OUT/$prev.csv" \
    $([ "$k" -lt 3 ] && echo --write-session "$S") | grep timing
  prev="round-$k"
done
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
for k in ("true", 1, 2, 3, 4):
    t = json.load(open(f"{out}/estimate-{k}/summary.json"))["timing"]
    print(f"estimate {k}: offset {t['encoder_time_offset_ms']['value']:.2f} +- {t['encoder_time_offset_ms']['sigma']:.2f} ms "
          f"(true {offset}), readout {t['readout_ms']['value']:.2f} +- {t['readout_ms']['sigma']:.2f} ms (true {readout})")
print("| run | self-check |rotation error| at >= 30 deg/s, median (deg) | [30,100) abs_rel | [30,100) point_mm_p50 |")
print("|---|---|---|---|")
for name in ("true", "zero", "round-1", "round-2", "round-3"):
    e, n = motion_error(name)
    a, p, f = band(name)
    print(f"| {name} | {e:.4f} ({n} frames) | {a:.4f} | {p:.1f} ({f} frames) |")
PY
