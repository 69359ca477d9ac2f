"""Image files for the scripts that read what `abvs` writes or what datasets ship, without an imaging
package in the Python environment: 8-bit PNG (first channel) and PFM.

    from image_io import pfm, png_first_channel   (the scripts' directory is on sys.path when run)"""
import struct
import zlib

import numpy as np


def pfm(path):
    """A little-endian one-channel PFM as float32, rows top to bottom (PFM stores them bottom up)."""
    b = open(path, "rb").read()
    head = b.split(b"\n", 3)
    w, h = map(int, head[1].split())
    d = np.frombuffer(head[3][: w * h * 4], "<f4").reshape(h, w)[::-1].astype(np.float32)
    return d


def png_first_channel(path):
    """An 8-bit grayscale / RGB / RGBA, non-interlaced PNG: its first channel (uint8, rows top to bottom)."""
    b = open(path, "rb").read()
    pos, idat, hdr = 8, b"", None
    while pos < len(b):
        n, t = struct.unpack(">I4s", b[pos : pos + 8])
        if t == b"IHDR":
            hdr = struct.unpack(">IIBBBBB", b[pos + 8 : pos + 8 + n])
        elif t == b"IDAT":
            idat += b[pos + 8 : pos + 8 + n]
        pos += 12 + n
    w, h, depth, ctype, _, _, inter = hdr
    assert depth == 8 and inter == 0, f"{path}: only 8-bit non-interlaced PNG"
    ch = {0: 1, 2: 3, 4: 2, 6: 4}[ctype]
    raw = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(h, 1 + w * ch)
    out = np.zeros((h, w * ch), np.int32)
    prev = np.zeros(w * ch, np.int32)
    for y in range(h):
        f, row = raw[y, 0], raw[y, 1:].astype(np.int32)
        if f == 0:
            cur = row
        elif f == 2:
            cur = (row + prev) & 255
        else:
            cur = np.zeros_like(row)
            for i in range(len(row)):
                a = cur[i - ch] if i >= ch else 0
                c = prev[i - ch] if i >= ch else 0
                p = {1: a, 3: (a + prev[i]) // 2}.get(f)
                if p is None:  # Paeth
                    pa, pb, pc = abs(prev[i] - c), abs(a - c), abs(a + prev[i] - 2 * c)
                    p = a if pa <= pb and pa <= pc else (prev[i] if pb <= pc else c)
                cur[i] = (row[i] + p) & 255
        out[y], prev = cur, cur
    return out.reshape(h, w, ch)[:, :, 0].astype(np.uint8)
