#!/usr/bin/env bash
# The ROS 2 outputs' cost on the critical path: paced replays of the fixture (25 fps, default ONNX engine,
# iceoryx2 publishing on as in the default run) without them, with --zenoh (connected to a Python listener
# on loopback that receives every key, Zenoh shared memory on in its session), with --zenoh --ros2-keys
# rmw-zenoh (the same listener, rmw_zenoh's keys), each with the runtime's shared memory on (the default:
# `zenoh`, `rmw`) and off (`[bridges.zenoh] shared_memory = false`: `zshmoff`, `rshmoff`), with --mcap,
# and with both, interleaved in rotating order ROUNDS times (ABVS_CFGS="off zenoh ..." picks
# configurations); prints each configuration's
# median end-to-end latency p50, the median of its ratio to the paired run without, the stage p50s, what
# the outputs counted (frames written / dropped, write ms a frame) and the runtime's own CPU accounting:
# the process's CPU ms a frame, the paired difference to the run without (median) as a share of the run
# without, and the Zenoh threads' CPU (the sink's `abvs-zenoh` thread + Zenoh's own) as a share of the
# process's, then with the sink's copy on the output thread (`copy_cpu_ms_per_frame`) added: the outputs'
# whole cost. ABVS_B=<another abvs binary> also runs --zenoh and rmw-zenoh with it (`zenohB`, `rmwB`) in
# the same rounds, to compare two builds.
#   cargo build --release -p abvs && scripts/setup.sh && scripts/bench_ros2_outputs.sh [ROUNDS=8] [FRAMES=125] [flags]
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
ROUNDS=${1:-8}
FRAMES=${2:-125}
shift $(( $# < 2 ? $# : 2 ))
BIN=${ABVS:-target/release/abvs}
PY=${ABVS_PYTHON:-.deps/python/bin/python3}
OUT=$(mktemp -d)
PORT=$(( 20000 + RANDOM % 20000 ))
# the consumer: counts bytes per key (decoding is the consumer's business, not the runtime's)
"$PY" - "tcp/127.0.0.1:$PORT" <<'PY' &
import json, sys, threading, zenoh
c = zenoh.Config()
c.insert_json5("mode", '"peer"')
c.insert_json5("listen/endpoints", json.dumps([sys.argv[1]]))
c.insert_json5("scouting/multicast/enabled", "false")
c.insert_json5("transport/shared_memory/enabled", "true")
s = zenoh.open(c)
n = {}
subs = [s.declare_subscriber(k, lambda x: n.__setitem__(str(x.key_expr), n.get(str(x.key_expr), 0) + 1))
        for k in ["abvs/depth", "abvs/camera_info", "abvs/points", "tf", "abvs/joint_states", "abvs/fovea/**", "abvs/confidence",
                  "0/abvs/**",
                  "0/tf/**"]]
threading.Event().wait()
PY
LISTENER=$!
trap 'kill $LISTENER 2>/dev/null; rm -rf "$OUT"' EXIT
sleep 2
# the runtime's shared memory off: the effective configuration with `shared_memory = false`
"$BIN" run --print-config | sed 's/^shared_memory = true/shared_memory = false/' >"$OUT/shmoff.toml"
grep -q '^shared_memory = false' "$OUT/shmoff.toml"
read -r -a cfgs <<<"${ABVS_CFGS:-off zenoh zshmoff rmw rshmoff mcap both}"
[ -n "${ABVS_B:-}" ] && cfgs+=(zenohB rmwB)
N=${#cfgs[@]}
for i in $(seq 1 "$ROUNDS"); do
  for j in $(seq 0 $(( N - 1 ))); do
    m=${cfgs[$(( (i + j) % N ))]}
    bin=$BIN
    case $m in
      off) extra=() ;;
      zenoh) extra=(--zenoh-connect "tcp/127.0.0.1:$PORT") ;;
      rmw) extra=(--zenoh-connect "tcp/127.0.0.1:$PORT" --ros2-keys rmw-zenoh) ;;
      zshmoff) extra=(--config "$OUT/shmoff.toml" --zenoh-connect "tcp/127.0.0.1:$PORT") ;;
      rshmoff) extra=(--config "$OUT/shmoff.toml" --zenoh-connect "tcp/127.0.0.1:$PORT" --ros2-keys rmw-zenoh) ;;
      mcap) extra=(--mcap "$OUT/run.mcap") ;;
      both) extra=(--zenoh-connect "tcp/127.0.0.1:$PORT" --mcap "$OUT/run.mcap") ;;
      zenohB) extra=(--zenoh-connect "tcp/127.0.0.1:$PORT"); bin=$ABVS_B ;;
      rmwB) extra=(--zenoh-connect "tcp/127.0.0.1:$PORT" --ros2-keys rmw-zenoh); bin=$ABVS_B ;;
    esac
    "$bin" run --quiet --truth-stride 0 --frames "$FRAMES" --service-prefix "abvs-bench-$$" "${extra[@]}" "$@" \
      --stats-json "$OUT/$m-$i.json" >/dev/null 2>&1
    rm -f "$OUT/run.mcap"
  done
done
python3 - "$OUT" "$ROUNDS" "${cfgs[@]}" <<'PY'
import json, statistics as st, sys
out, n, cfgs = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
load = lambda m: [json.load(open(f"{out}/{m}-{i}.json")) for i in range(1, n + 1)]
off = load("off") if "off" in cfgs else None
# Zenoh's own threads (its runtime's pools) by name, and the sink's thread
ZENOH_THREADS = ("abvs-zenoh", "app-", "acc-", "net-", "rx-", "tx-")
for m in cfgs:
    vs = load(m)
    e = [v["latency_ms"]["p50"] for v in vs]
    r = [v["latency_ms"]["p50"] / o["latency_ms"]["p50"] for v, o in zip(vs, off or vs)]
    line = (f"{m:6} end-to-end p50 median {st.median(e):6.2f} ms, paired ratio median {st.median(r):.3f}; stage p50 "
            + " ".join(f"{k} {st.median([v['stages'][k]['p50'] for v in vs]):.2f}" for k in ["rectify", "disparity", "output"]))
    cpu = [v["cpu"]["ms_per_frame"] for v in vs]
    d = [v["cpu"]["ms_per_frame"] - o["cpu"]["ms_per_frame"] for v, o in zip(vs, off or vs)]
    z = [sum(ms for n, ms in v["cpu"]["other_threads_by_name_ms_per_frame"].items() if n.startswith(ZENOH_THREADS))
         / v["cpu"]["ms_per_frame"] for v in vs]
    line += (f"; CPU {st.median(cpu):.2f} ms a frame, paired difference to off {st.median(d):+.2f} ms"
             f" ({100 * st.median(d) / st.median([o['cpu']['ms_per_frame'] for o in off or vs]):+.1f} %),"
             f" Zenoh threads {100 * st.median(z):.2f} % of it")
    if "zenoh" in vs[0]:
        # the Zenoh output's whole cost: its threads and the sink's copy on the output thread, per frame
        w = [(sum(ms for n, ms in v["cpu"]["other_threads_by_name_ms_per_frame"].items() if n.startswith(ZENOH_THREADS))
              + v["zenoh"].get("copy_cpu_ms_per_frame", 0.0)) / v["cpu"]["ms_per_frame"] for v in vs]
        line += f", with the output thread's copy {100 * st.median(w):.2f} %"
        wr = [v["zenoh"].get("writer") or {} for v in vs]
        line += (f"; shm messages {sum(x.get('shm_messages', 0) for x in wr)} fallbacks"
                 f" {sum(x.get('shm_fallbacks', 0) for x in wr)}, skipped {sum(v['zenoh'].get('messages_skipped', 0) for v in vs)}")
    for k in ["zenoh", "mcap"]:
        if k in vs[0] and "copy_cpu_ms_per_frame" in vs[0][k]:
            line += f"; {k} copy {st.median([v[k]['copy_cpu_ms_per_frame'] for v in vs]):.2f} ms a frame"
        if k in vs[0]:
            line += (f"; {k} written {sum(v[k]['frames_written'] for v in vs)} dropped {sum(v[k]['frames_dropped'] for v in vs)}"
                     f" of {sum(v[k]['frames_in'] for v in vs)}, {st.median([v[k]['write_ms_p50'] for v in vs]):.2f} ms a frame")
    print(line)
    if "zenoh" in vs[0]:
        # thread by thread (ms a frame, median): what the share is made of
        names = sorted({n for v in vs for n in v["cpu"]["other_threads_by_name_ms_per_frame"] if n.startswith(ZENOH_THREADS)})
        parts = [f"{n} {st.median([v['cpu']['other_threads_by_name_ms_per_frame'].get(n, 0.0) for v in vs]):.3f}" for n in names]
        print(f"{'':6}   threads (ms a frame): " + ", ".join(parts)
              + f", output thread's copy {st.median([v['zenoh'].get('copy_cpu_ms_per_frame', 0.0) for v in vs]):.3f}")
PY
