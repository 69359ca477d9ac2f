#!/bin/bash
# Renders a session (seed $1, 320x240, ${FRAMES:-40} frames at ${FPS:-25} fps, fixations at ${FIXATION_M:-0.55..1.3} m)
# and runs the self-check on it: with both eyes' FK set to their true units (none), and with the left or the right
# eye's unit given +1 % encoder scale (an error injected into one eye's calibration); prints each verdict
# (docs/self-check.md, issue 37). EYES="none left right" by default: which runs.
# Usage: scripts/self_check_wrong_eye.sh SEED [OUTDIR]; ABVS=target/debug/abvs by default.
set -euo pipefail
B=${ABVS:-target/debug/abvs}
PY=${PY:-.deps/python/bin/python}
S=$1; O=${2:-/tmp/wrong_eye}; F=${FRAMES:-40}; FPS=${FPS:-25}; FM=${FIXATION_M:-0.55..1.3}; D=$O/s$S-$F-$FPS-$FM
mkdir -p "$O"
[ -d "$D" ] || nice -n 19 "$B" sim session --out "$D" --seed "$S" --frames "$F" --width 320 --height 240 \
  --fk-method mh --pursuit-deg-s 30 --fps "$FPS" --fixation-m "$FM" > /dev/null
for v in ${EYES:-none left right}; do
  C=$D-$v; rm -rf "$C"; cp -r "$D" "$C"
  for e in 0 1; do
    W=0; { [ $v = left ] && [ $e = 0 ]; } && W=1; { [ $v = right ] && [ $e = 1 ]; } && W=1
    "$PY" - "$C/truth/unit$e.toml" "$C/calib/eye$e.toml" $W <<'PY'
import re, sys
src, dst, wrong = sys.argv[1], sys.argv[2], sys.argv[3] == '1'
t = open(src).read()
if wrong:
    m = re.search(r'\[effects\.encoder_scale\]\n(.*?)(?=\n\[|\Z)', t, re.S)
    body = re.sub(r'enabled = \w+', 'enabled = true', m.group(1))
    body = re.sub(r'relative_error = \[([^\]]*)\]',
                  lambda k: 'relative_error = [' + ', '.join(repr(float(x) + 0.01) for x in k.group(1).split(',')) + ']', body)
    t = t[:m.start(1)] + body + t[m.end(1):]
open(dst, 'w').write(t)
PY
    sed -i "s#\"calib/eye$e\"#\"calib/eye$e.toml\"#" "$C/session.toml"
  done
  nice -n 19 "$B" run --session "$C" --resolution 320x240 --no-publish --engine sgbm --lossless --truth-stride 0 \
    --self-check-every 1 --self-check-log "$C.csv" > "$C.run.out" 2>&1
  nice -n 19 "$B" calib self-check --log "$C.csv" --out "$C.report" --rounds 0 > "$C.check.out" 2>&1
  head -1 "$C.check.out" | sed "s/^/seed $S $v: /"
done
