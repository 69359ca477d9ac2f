#!/usr/bin/env bash
# What the gaze service costs a replay with no goals (issue 36: under 2 % CPU per frame): `abvs run` on the
# embedded fixture with the gaze service on (the default: the controller's stage, the iceoryx2 goal and state
# services) and off (`--no-gaze`, the same binary), publishing over iceoryx2 as deployed, in alternating order,
# ROUNDS times each in two modes: lossless (every frame processed, deterministic) and paced (the recorded
# 25 fps, `abvs run` as the README runs it). Reads the runtime's own CPU accounting (stats JSON `cpu`: the
# whole process per frame, and the lanes the service runs on) and prints per mode the medians, the median of
# the paired ratios on/off, and the service's own CPU (`gaze_cpu`, `gaze_iceoryx2`) against the process's.
# Also checks that both arms' lossless depth is bit-identical (`output_digest`).
#   scripts/bench_gaze_cost.sh [ABVS=target/release/abvs] [ROUNDS=6] [FRAMES=50] [extra abvs run flags]
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
ABVS=${1:-target/release/abvs}
ROUNDS=${2:-6}
FRAMES=${3:-50}
shift $(( $# < 3 ? $# : 3 ))
OUT=$(mktemp -d)
trap 'rm -rf "$OUT"' EXIT
for i in $(seq 1 "$ROUNDS"); do
  for mode in lossless paced; do
    # alternate which arm runs first: drift in the machine's load falls on both
    if (( i % 2 )); then arms=(on off); else arms=(off on); fi
    for arm in "${arms[@]}"; do
      extra=()
      [[ $arm == off ]] && extra+=(--no-gaze)
      [[ $mode == lossless ]] && extra+=(--lossless)
      "$ABVS" run --quiet --frames "$FRAMES" --truth-stride 0 --no-self-check \
        --service-prefix "abvs-bench-gaze-$$-$i-$mode-$arm" "${extra[@]}" "$@" \
        --stats-json "$OUT/$mode-$arm-$i.json" >/dev/null 2>&1
    done
  done
done
python3 - "$OUT" "$ROUNDS" <<'PY'
import json, statistics as st, sys
out, n = sys.argv[1], int(sys.argv[2])
load = lambda mode, arm: [json.load(open(f"{out}/{mode}-{arm}-{i}.json")) for i in range(1, n + 1)]
for mode in ["lossless", "paced"]:
    on, off = load(mode, "on"), load(mode, "off")
    cpu = lambda v: v["cpu"]["ms_per_frame"]
    lane = lambda v, l: v["cpu"]["lanes_ms_per_frame"][l]
    ratio = [cpu(a) / cpu(b) for a, b in zip(on, off)]
    own = [(a["gaze_cpu"]["stage_us_per_frame"] + a["gaze_iceoryx2"]["cpu_us_per_frame"]) * 1e-3 / cpu(a) for a in on]
    print(f"{mode:8} process CPU per frame median: on {st.median(map(cpu, on)):.2f} ms, off {st.median(map(cpu, off)):.2f} ms; "
          f"paired ratio on/off median {st.median(ratio):.4f} (min {min(ratio):.4f}, max {max(ratio):.4f}); "
          f"rectify lane on/off {st.median([lane(v, 'rectify') for v in on]):.3f}/{st.median([lane(v, 'rectify') for v in off]):.3f} ms, "
          f"output lane {st.median([lane(v, 'output') for v in on]):.3f}/{st.median([lane(v, 'output') for v in off]):.3f} ms; "
          f"the service's own CPU: stage {st.median([v['gaze_cpu']['stage_us_per_frame'] for v in on]):.1f} us + "
          f"iceoryx2 {st.median([v['gaze_iceoryx2']['cpu_us_per_frame'] for v in on]):.1f} us per frame = "
          f"{100 * st.median(own):.3f} % of the process; frames in {st.median([v['frames_in'] for v in on]):.0f}, "
          f"published on/off {st.median([v['frames_published'] for v in on]):.0f}/{st.median([v['frames_published'] for v in off]):.0f}")
    if mode == "lossless":
        digests = {v["output_digest"] for v in on + off}
        print(f"lossless output digests on and off: {sorted(digests)} ({'identical' if len(digests) == 1 else 'DIFFERENT'})")
        assert all("gaze" not in v for v in off), "the gaze service ran with --no-gaze"
PY
