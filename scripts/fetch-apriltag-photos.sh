#!/usr/bin/env bash
# Real AprilTag (tag36h11) photos with reference corners, for abvs-camcal's detector tests:
# the AprilTag library's own test set (3 NASA Swarmathon photos, 799x533, CC BY-SA 2.0, with the
# corners AprilTag 3 detects in each), as vendored by the crates.io crate apriltag-sys 0.4.0.
# Fetched with cargo (the ordinary crates.io client) into .deps/apriltag-photos/. Idempotent.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
out="$root/.deps/apriltag-photos"
if [ -f "$out/34139872896_defdb2f8d9_c.txt" ]; then
  echo "[fetch-apriltag-photos] present: $out"
  exit 0
fi
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
mkdir -p "$tmp/p/src"
cat > "$tmp/p/Cargo.toml" <<'TOML'
[package]
name = "fetch-apriltag-photos"
version = "0.0.0"
edition = "2021"
[dependencies]
apriltag-sys = "=0.4.0"
TOML
echo "" > "$tmp/p/src/lib.rs"
cargo fetch --quiet --manifest-path "$tmp/p/Cargo.toml"
crate="$(ls "${CARGO_HOME:-$HOME/.cargo}"/registry/cache/*/apriltag-sys-0.4.0.crate | head -n1)"
mkdir -p "$out"
tar xzf "$crate" -C "$tmp" apriltag-sys-0.4.0/apriltag-src/test/data
cp "$tmp"/apriltag-sys-0.4.0/apriltag-src/test/data/* "$out/"
echo "[fetch-apriltag-photos] wrote $out"
