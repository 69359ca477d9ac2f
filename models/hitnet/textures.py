"""Texture pool for the rendered stereo training data.

Textures are natural images that registry packages ship on this machine:
  * Debian `opencv-doc`: /usr/share/doc/opencv-doc/examples/data/*.jpg|png
  * scikit-image's bundled data directory (skimage/data/*.png|jpg), only files
    that are already on disk (nothing is downloaded).

Every image from a stereo / optical-flow benchmark (Middlebury, KITTI, ETH3D,
...) is EXCLUDED, by file-name pattern and by SHA-256. In particular the
Middlebury Aloe pair (aloeL.jpg, aloeR.jpg, aloeGT.png) is our real-image
benchmark and must never be used as a texture or for training.
"""
from __future__ import annotations

import glob
import hashlib
import os
import re

OPENCV_DOC_DATA = "/usr/share/doc/opencv-doc/examples/data"

# File-name patterns (case-insensitive, matched against the base name).
EXCLUDE_NAME_PATTERNS = [
    r"aloe",            # Middlebury Aloe (our real benchmark: aloeL/aloeR/aloeGT)
    r"rubberwhale",     # Middlebury optical-flow
    r"basketball",      # Middlebury optical-flow
    r"^left\d*\.",      # left.jpg/right.jpg: unknown stereo pair; leftNN/rightNN: stereo calibration pairs
    r"^right\d*\.",
    r"motorcycle",      # Middlebury 2014 Motorcycle (scikit-image stereo_motorcycle)
    r"tsukuba", r"teddy", r"cones", r"venus", r"sawtooth", r"^art", r"dolls",
    r"moebius", r"reindeer", r"laundry", r"books", r"baby", r"bowling",
    r"cloth", r"flowerpots", r"lampshade", r"midd", r"monopoly", r"plastic",
    r"rocks", r"wood", r"adirondack", r"jadeplant", r"pipes", r"playroom",
    r"playtable", r"recycle", r"shelves", r"vintage", r"piano", r"pipe",
    r"middlebury", r"kitti", r"eth3d", r"dimetrodon", r"grove", r"hydrangea",
    r"urban", r"venus", r"groundtruth", r"_gt\.", r"gt\.png$", r"disp",
    r"stereo", r"flow",
]

# SHA-256 of files that must never be in the pool, whatever their name.
EXCLUDE_SHA256 = {
    "cce5736808efe80d9f04b118dbb978c344d4345672b332718c3e039a3eeb8eee": "aloeL.jpg (Middlebury Aloe)",
    "9b23100df31a846bc6e6a6545563b2b4120b948c9835c7d36cde00af77f4503e": "aloeR.jpg (Middlebury Aloe)",
    "39ce4f3cb48d797d1091c5152f93361d8104298c337f8a1c134d87dda3442c04": "aloeGT.png (Middlebury Aloe GT)",
    "fb314330c3eb0a81651c682803e73b348898157267fbc37c4c2c07d1b3a8e321": "left.jpg (unknown stereo pair)",
    "20972954be263a99194d1373d9a5cd8d2dc92acf69b55470b6951f3b3475017f": "right.jpg (unknown stereo pair)",
}

# Not benchmark data, but useless as textures (tiny / synthetic / masks / logos).
SKIP_NAMES = {
    "mask.png", "gradient.png", "opencv-logo.png", "opencv-logo-white.png",
    "LinuxLogo.jpg", "WindowsLogo.jpg", "detect_blob.png", "ellipses.jpg",
    "chessboard.png", "digits.png", "imageTextN.png", "imageTextR.png",
    "alphabet_36.txt", "ml.png", "pca_test1.jpg", "templ.png", "tmpl.png",
    "checker_bilevel.png", "logo.png", "horse.png", "phantom.png",
    "microaneurysms.png", "hubble_deep_field.jpg", "binary_blobs.png",
}

IMAGE_EXT = (".jpg", ".jpeg", ".png")


def sha256_file(path: str) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def excluded_reason(path: str) -> str | None:
    """Why `path` must not be in the pool (None if it may be)."""
    base = os.path.basename(path).lower()
    for pat in EXCLUDE_NAME_PATTERNS:
        if re.search(pat, base):
            return f"name matches /{pat}/"
    if os.path.isfile(path):
        digest = sha256_file(path)
        if digest in EXCLUDE_SHA256:
            return f"sha256 of {EXCLUDE_SHA256[digest]}"
    return None


def candidate_files() -> list[str]:
    files = []
    for ext in IMAGE_EXT:
        files += glob.glob(os.path.join(OPENCV_DOC_DATA, "*" + ext))
    try:
        import skimage  # noqa: F401
        skdir = os.path.join(os.path.dirname(skimage.__file__), "data")
        for ext in IMAGE_EXT:
            files += glob.glob(os.path.join(skdir, "*" + ext))
    except ImportError:
        pass
    return sorted(set(files))


def texture_pool(verbose: bool = False) -> list[str]:
    """Sorted list of texture files (deterministic order for seeding)."""
    pool = []
    for f in candidate_files():
        if os.path.basename(f) in SKIP_NAMES:
            continue
        why = excluded_reason(f)
        if why:
            if verbose:
                print(f"excluded {f}: {why}")
            continue
        if os.path.getsize(f) < 20_000:  # tiny icons are no texture
            continue
        pool.append(f)
    return pool


def pool_sha256(pool: list[str]) -> dict[str, str]:
    return {os.path.basename(p) + "@" + os.path.dirname(p): sha256_file(p) for p in pool}


if __name__ == "__main__":
    p = texture_pool(verbose=True)
    print(f"{len(p)} textures:")
    for f in p:
        print("  ", f)
