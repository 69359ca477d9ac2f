#!/usr/bin/env bash
# The closed-loop gaze benchmark (issue 36, docs/gaze.md "The closed loop in simulation"): the simulated head
# at 640x480, 25 fps, readout 20 ms, exposure 4 ms, playing scripts/gaze_bench.txt (10 fixations at 0.3-2 m
# across the workspace, then a point moving at 20 deg/s), on seeds never used in development, with the
# hybrid-calibrated FK (from simulated measurements) and the nominal FK beside it. Prints each run's gaze
# scores from the stats JSON. Deterministic: a second run prints the same numbers.
#   scripts/bench_gaze_sim.sh [ABVS=target/release/abvs] [SEEDS="21 22"] [extra abvs run flags]
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
ABVS=${1:-target/release/abvs}
SEEDS=${2:-21 22}
shift $(( $# < 2 ? $# : 2 ))
OUT=$(mktemp -d)
for seed in $SEEDS; do
  for fk in calibrated nominal; do
    "$ABVS" run --source sim --seed "$seed" --frames 160 --width 640 --height 480 --fk "$fk" \
      --gaze-script scripts/gaze_bench.txt --sim-calib "$OUT/calib-$seed" --no-publish --no-self-check \
      --truth-stride 0 --quiet --stats-json "$OUT/$seed-$fk.json" "$@"
  done
done
python3 - "$OUT" $SEEDS <<'PY'
import json, sys
out, seeds = sys.argv[1], sys.argv[2:]
print("seed fk          goals refused settled fix_p50  fix_max  settle_p50 settle_max planned_p50 pursuit_p50 "
      "late gated moving_ungated seq_gaps digest")
for s in seeds:
    for fk in ["calibrated", "nominal"]:
        j = json.load(open(f"{out}/{s}-{fk}.json"))
        g = j["gaze"]
        f = lambda k, q: "-" if g[k][q] is None else f"{g[k][q]:.4f}"
        print(f"{s:<4} {fk:<11} {g['goals']:>5} {sum(g['refused'].values()):>7} {g['settled']:>7} "
              f"{f('fixation_error_deg','p50'):>8} {f('fixation_error_deg','max'):>8} {f('settle_ms','p50'):>10} "
              f"{f('settle_ms','max'):>10} {f('planned_ms','p50'):>11} {f('pursuit_error_deg','p50'):>11} "
              f"{g['goals_settled_late']:>4} {g['frames_gated_saccade']:>5} {g['frames_moving_ungated']:>14} {g['seq_gaps']:>8} {j['output_digest']}")
PY
