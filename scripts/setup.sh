#!/usr/bin/env bash
# Installs everything abvs needs on a fresh Debian/Ubuntu machine (run as root or with sudo):
#   - system libraries from Debian: OpenCV 4 (+ clang/libclang for the opencv and v4l bindings);
#     opencv-doc ships the real test images (chessboard stereo set, Middlebury Aloe) the tests use; OpenBLAS
#     as the system's BLAS and LAPACK (Debian's alternatives; OpenCV links the reference ones, on which
#     `abvs calib stereo`'s fisheye adjustment of 75 pairs spent 90 of its 115 s in dgemm: 28 s with OpenBLAS).
#     Its serial flavour: the pthread one's parallel LU (dgetrf_parallel) overran a 2 MiB thread stack (Rust's
#     test and spawned threads) inside OpenCV's fisheye calibration and crashed one run in two
#   - the ONNX Runtime shared library, taken from the onnxruntime wheel on PyPI and unpacked into
#     .deps/onnxruntime/ inside this checkout, where the built `abvs` finds it without any variable
#   - a Python environment in .deps/python (pinned packages from PyPI) for the Python subscriber
#     (python/abvs_iceoryx2.py) and the tests that check the runtime's outputs from Python
# Idempotent: a second run only checks.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
ORT_VERSION=1.31.1
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi

pkgs=(build-essential pkg-config clang libclang-dev libopencv-dev opencv-doc libopenblas0-serial python3-pip python3-venv unzip curl fonts-dejavu-core)
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ "${#missing[@]}" -gt 0 ]; then
  echo "[setup] installing Debian packages: ${missing[*]}"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

if ! command -v cargo >/dev/null 2>&1; then
  echo "[setup] cargo not found: installing the Rust toolchain via rustup is required" >&2
  exit 1
fi

ort_dir="$root/.deps/onnxruntime"
ort_lib="$ort_dir/libonnxruntime.so.$ORT_VERSION"
if [ ! -f "$ort_lib" ]; then
  echo "[setup] fetching onnxruntime==$ORT_VERSION wheel from PyPI for its shared library"
  tmp="$(mktemp -d)"
  python3 -m pip download --quiet --no-deps --only-binary=:all: -d "$tmp" "onnxruntime==$ORT_VERSION"
  whl="$(ls "$tmp"/onnxruntime-*.whl | head -n1)"
  mkdir -p "$ort_dir"
  unzip -q -j -o "$whl" "onnxruntime/capi/libonnxruntime.so.$ORT_VERSION" -d "$ort_dir"
  ln -sf "libonnxruntime.so.$ORT_VERSION" "$ort_dir/libonnxruntime.so"
  rm -rf "$tmp"
fi
echo "[setup] ONNX Runtime: $ort_lib"

# Python: iceoryx2 of the runtime's iceoryx2 version (0.10), Zenoh of its zenoh version (1.10), rosbags
# (CDR of the ROS 2 Humble types), mcap + mcap-ros2-support (reading the recordings), numpy.
py_dir="$root/.deps/python"
py_pkgs=(numpy==2.4.6 iceoryx2==0.10.0 eclipse-zenoh==1.10.2 rosbags==0.11.9 mcap==1.6.0 mcap-ros2-support==0.6.0)
py_stamp="$py_dir/.abvs-packages"
if [ ! -x "$py_dir/bin/python3" ] || [ "$(cat "$py_stamp" 2>/dev/null)" != "${py_pkgs[*]}" ]; then
  echo "[setup] Python environment $py_dir: ${py_pkgs[*]}"
  python3 -m venv "$py_dir"
  "$py_dir/bin/python3" -m pip install --quiet --disable-pip-version-check "${py_pkgs[@]}"
  echo "${py_pkgs[*]}" > "$py_stamp"
fi
"$py_dir/bin/python3" -c "import numpy, iceoryx2, zenoh, rosbags, mcap, mcap_ros2"
echo "[setup] Python: $py_dir/bin/python3"
"$root/scripts/fetch-apriltag-photos.sh"
"$root/scripts/fetch-middlebury-motorcycle.sh"
echo "[setup] done"
