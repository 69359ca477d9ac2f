"""Points the eyes of a running runtime at a few points, using only abvs_iceoryx2 (and the standard library),
and prints each goal's settled state as one JSON object on its last line (cli/tests/sim_gaze_python.rs runs it
against `abvs run --source sim`).

  gaze_points.py PREFIX X,Y,Z [X,Y,Z ...]

For each point: look_at, then wait for a state that reports the goal's id in phase "settled" (a state
"refused" for it, or none in 60 s, ends the script with an error). States are read as they come; a frame's
state is published once per frame.
"""
import json
import math
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import abvs_iceoryx2 as abvs  # noqa: E402


def fields(s):
    nan_none = lambda v: None if isinstance(v, float) and math.isnan(v) else v  # noqa: E731
    return {
        "seq": s.seq,
        "goal_id": s.goal_id,
        "phase": s.phase,
        "reason": s.reason,
        "commanded_fixation": [nan_none(v) for v in s.commanded_fixation],
        "measured_fixation": [nan_none(v) for v in s.measured_fixation],
        "vergence_m": nan_none(s.vergence_m),
        "planned_ms": s.planned_ms,
        "gated_saccade": s.gated_saccade,
        "gated": s.gated,
    }


def main(prefix, points):
    out = {"goals": []}
    with abvs.Gaze(prefix) as gaze:
        first = gaze.state(timeout_s=60.0)
        if first is None:
            print(json.dumps({"error": "no gaze state in 60 s"}))
            return 1
        out["first"] = fields(first)
        for p in points:
            goal = gaze.look_at(*p)
            seen = []
            deadline = time.monotonic() + 60.0
            settled = None
            while settled is None:
                if time.monotonic() > deadline:
                    print(json.dumps({"error": f"goal {goal} did not settle in 60 s", "seen": seen, **out}))
                    return 1
                s = gaze.state(timeout_s=1.0)
                if s is None or s.goal_id != goal:
                    continue
                seen.append(s.phase)
                if s.phase == "refused":
                    print(json.dumps({"error": f"goal {goal} refused: {s.reason}", **out}))
                    return 1
                if s.phase == "settled":
                    settled = s
            out["goals"].append({"id": goal, "point": list(p), "phases": seen, "state": fields(settled)})
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    pts = [tuple(float(v) for v in a.split(",")) for a in sys.argv[2:]]
    sys.exit(main(sys.argv[1], pts))
