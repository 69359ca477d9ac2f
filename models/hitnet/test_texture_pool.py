#!/usr/bin/env python3
"""Fails if any benchmark image (Middlebury / KITTI / ETH3D, the unknown left/right pair)
is in the texture pool used by gen_data.py.

  python models/hitnet/test_texture_pool.py        (or: pytest models/hitnet/test_texture_pool.py)
"""
import os
import re
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from textures import (EXCLUDE_NAME_PATTERNS, EXCLUDE_SHA256, OPENCV_DOC_DATA,  # noqa: E402
                      candidate_files, excluded_reason, sha256_file, texture_pool)

MUST_BE_EXCLUDED = ["aloeL.jpg", "aloeR.jpg", "aloeGT.png", "rubberwhale1.png", "rubberwhale2.png",
                    "basketball1.png", "basketball2.png", "left.jpg", "right.jpg",
                    "motorcycle_left.png", "motorcycle_right.png"]


def test_pool_has_no_excluded_file():
    pool = texture_pool()
    assert len(pool) >= 20, f"texture pool too small: {len(pool)}"
    names = {os.path.basename(p).lower() for p in pool}
    for n in MUST_BE_EXCLUDED:
        assert n.lower() not in names, f"{n} is in the texture pool"
    for p in pool:
        base = os.path.basename(p).lower()
        for pat in EXCLUDE_NAME_PATTERNS:
            assert not re.search(pat, base), f"{p} matches excluded pattern {pat}"
        assert sha256_file(p) not in EXCLUDE_SHA256, f"{p} has the SHA-256 of an excluded file"


def test_aloe_hashes_are_the_installed_files():
    # The SHA-256 list must really describe the Aloe files on this machine (if installed).
    for n in ["aloeL.jpg", "aloeR.jpg", "aloeGT.png"]:
        p = os.path.join(OPENCV_DOC_DATA, n)
        if os.path.exists(p):
            assert sha256_file(p) in EXCLUDE_SHA256, f"{p}: SHA-256 not in the exclusion list"


def test_exclusion_by_hash_even_if_renamed(tmp_path=None):
    import shutil
    import tempfile
    src = os.path.join(OPENCV_DOC_DATA, "aloeL.jpg")
    if not os.path.exists(src):
        return
    d = tempfile.mkdtemp()
    dst = os.path.join(d, "innocent_texture.jpg")
    shutil.copy(src, dst)
    assert excluded_reason(dst) is not None
    shutil.rmtree(d)


def test_candidates_cover_excluded_files():
    # the pool really had to filter them (they are candidates on this machine)
    cands = {os.path.basename(p) for p in candidate_files()}
    if os.path.isdir(OPENCV_DOC_DATA):
        assert "aloeL.jpg" in cands


if __name__ == "__main__":
    fails = 0
    tests = [v for k, v in sorted(globals().items()) if k.startswith("test_")]
    for t in tests:
        try:
            t()
            print("PASS", t.__name__)
        except AssertionError as e:
            fails += 1
            print("FAIL", t.__name__, e)
    print(f"{len(tests) - fails} passed, {fails} failed")
    sys.exit(1 if fails else 0)
