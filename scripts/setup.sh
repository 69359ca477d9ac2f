#!/usr/bin/env bash
# Installs everything abvs needs on a fresh Debian/Ubuntu machine (run as root or with sudo):
#   - system libraries from Debian: OpenCV 4 (+ clang/libclang for the opencv and v4l bindings);
#     opencv-doc ships the real test images (chessboard stereo set, Middlebury Aloe) the tests use
#   - the ONNX Runtime shared library, taken from the onnxruntime wheel on PyPI and unpacked into
#     .deps/onnxruntime/ inside this checkout, where the built `abvs` finds it without any variable
# Idempotent: a second run only checks.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
ORT_VERSION=1.31.1
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi

pkgs=(build-essential pkg-config clang libclang-dev libopencv-dev opencv-doc python3-pip unzip curl fonts-dejavu-core)
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
"$root/scripts/fetch-apriltag-photos.sh"
echo "[setup] done"
