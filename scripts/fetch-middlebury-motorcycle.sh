#!/usr/bin/env bash
# A real stereo pair with dense ground truth that no model or choice of ours has seen: Middlebury 2014
# "Motorcycle" at quarter size (741x500; Scharstein et al., GCPR 2014), as scikit-image 0.26.0 ships it
# on PyPI (skimage/data/motorcycle_{left,right}.png, motorcycle_disp.npz). Taken from the wheel with pip
# (no install), checked by SHA-256, the ground truth written as PFM (inf = unknown) into
# .deps/stereo/motorcycle/. It is the held-out final test of the disparity engines (models/hitnet/README.md).
# Idempotent.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
out="$root/.deps/stereo/motorcycle"
py="$root/.deps/python/bin/python3"
if [ -f "$out/disp0.pfm" ] && [ -f "$out/im0.png" ] && [ -f "$out/im1.png" ]; then
  echo "[fetch-middlebury-motorcycle] present: $out"
  exit 0
fi
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
python3 -m pip download --quiet --no-deps --only-binary=:all: --python-version 3.11 -d "$tmp" "scikit-image==0.26.0"
whl="$(ls "$tmp"/scikit_image-*.whl | head -n1)"
unzip -q -j -o "$whl" skimage/data/motorcycle_left.png skimage/data/motorcycle_right.png \
  skimage/data/motorcycle_disp.npz -d "$tmp"
(cd "$tmp" && sha256sum -c --quiet) <<'SUMS'
db18e9c4157617403c3537a6ba355dfeafe9a7eabb6b9b94cb33f6525dd49179  motorcycle_left.png
5fc913ae870e42a4b662314bc904d1786bcad8e2f0b9b67dba5a229406357797  motorcycle_right.png
2e49c8cebff3fa20359a0cc6880c82e1c03bbb106da81a177218281bc2f113d7  motorcycle_disp.npz
SUMS
mkdir -p "$out"
cp "$tmp/motorcycle_left.png" "$out/im0.png"
cp "$tmp/motorcycle_right.png" "$out/im1.png"
# PFM: "Pf", width height, -1 (little-endian), rows bottom to top; unknown (NaN/inf) written as inf
"$py" - "$tmp/motorcycle_disp.npz" "$out/disp0.pfm" <<'PY'
import sys, numpy as np
d = np.load(sys.argv[1])["arr_0"].astype("<f4")
d[~np.isfinite(d)] = np.inf
h, w = d.shape
with open(sys.argv[2], "wb") as f:
    f.write(b"Pf\n%d %d\n-1.0\n" % (w, h))
    f.write(np.ascontiguousarray(d[::-1]).tobytes())
PY
echo "[fetch-middlebury-motorcycle] wrote $out"
