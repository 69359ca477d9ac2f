#!/usr/bin/env bash
# Draws docs/oakd_mask.png (issue 41): census-refine on two real indoor OAK-D pairs (PyPI `stereodemo` 0.7,
# stereodemo/datasets/oak-d/: rectified 640x480, baseline 75 mm, fx 451 px, no ground truth), dense
# (`--min-confidence 0`) and as published by default (the validity mask), and prints how much of the band
# of wrong large disparities at the top of each image the default masks.
#   scripts/oakd_pictures.sh [ABVS=target/release/abvs]
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
abvs="${1:-target/release/abvs}"
py=.deps/python/bin/python3
data=.deps/stereodemo/stereodemo/datasets/oak-d
if [[ ! -e $data/desk_left.png ]]; then
  mkdir -p .deps/stereodemo
  "$py" -m pip download --quiet --no-deps --disable-pip-version-check -d .deps/stereodemo stereodemo==0.7
  (cd .deps/stereodemo && unzip -q -o stereodemo-0.7-py3-none-any.whl 'stereodemo/datasets/oak-d/*')
fi
out="$(mktemp -d)"
trap 'rm -rf "$out"' EXIT
for n in desk living_room; do
  cp "$data/${n}_left.png" "$out/"
  for c in 0 d; do
    flag=()
    [[ $c == 0 ]] && flag=(--min-confidence 0)
    "$abvs" disparity --engine census-refine --left "$data/${n}_left.png" --right "$data/${n}_right.png" \
      --out "$out/${n}_$c.pfm" "${flag[@]}"
  done
done
"$py" scripts/oakd_pictures.py docs/oakd_mask.png "$out" desk living_room
echo "wrote docs/oakd_mask.png ($(stat -c %s docs/oakd_mask.png) bytes)"
