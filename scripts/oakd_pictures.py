#!/usr/bin/env python3
"""Draws docs/oakd_mask.png from `abvs disparity --engine census-refine` outputs on the OAK-D pairs
(scripts/oakd_pictures.sh runs it): per pair a row of the left image, the dense disparity
(`--min-confidence 0`) and the default published one (masked pixels black), half size, one colormap over
both. Prints, per pair, how many of the top band's wrong large disparities the default masks.

    oakd_pictures.py OUT.png DIR NAME... (DIR/NAME_left.png, NAME_0.pfm dense, NAME_d.pfm default)"""
import struct
import sys
import zlib

import numpy as np

from image_io import pfm, png_first_channel


def turbo(t):
    """A 4-knot approximation of a perceptual rainbow: blue (far) to red (near)."""
    k = np.array([[48, 18, 59], [40, 160, 240], [120, 250, 90], [250, 180, 40], [180, 20, 10]], np.float32)
    x = np.clip(t, 0, 1) * (len(k) - 1)
    i = np.minimum(x.astype(int), len(k) - 2)
    f = (x - i)[..., None]
    return k[i] * (1 - f) + k[i + 1] * f


def write_palette_png(path, idx, pal):
    h, w = idx.shape
    raw = b"".join(b"\0" + idx[y].tobytes() for y in range(h))
    chunk = lambda t, d: struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n")
        f.write(chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 3, 0, 0, 0)))
        f.write(chunk(b"PLTE", pal.astype(np.uint8).tobytes()))
        f.write(chunk(b"IDAT", zlib.compress(raw, 9)))
        f.write(chunk(b"IEND", b""))


def main():
    out, d, names = sys.argv[1], sys.argv[2], sys.argv[3:]
    # palette: 0 black (masked / no estimate), 1..127 gray levels, 128..255 the colormap
    pal = np.zeros((256, 3), np.float32)
    pal[1:128] = np.linspace(0, 255, 127)[:, None]
    pal[128:] = turbo(np.linspace(0, 1, 128))
    rows = []
    for n in names:
        left = png_first_channel(f"{d}/{n}_left.png")
        dense, masked = (np.where(np.isfinite(a), a, np.nan) for a in (pfm(f"{d}/{n}_0.pfm"), pfm(f"{d}/{n}_d.pfm")))
        lo, hi = np.nanpercentile(dense, 2), np.nanpercentile(dense, 98)
        # the top band (the top 10 % of rows: ceiling and the wall's top, 2 m and more away): its wrong
        # disparities are those above twice the dense map's median (nearer than half the scene's depth)
        band, wrong = dense[: dense.shape[0] // 10], 2 * np.nanmedian(dense)
        big, kept = band > wrong, masked[: dense.shape[0] // 10]
        print(
            f"{n}: top band (rows 0..{band.shape[0] - 1}): {big.mean():.3f} of its pixels dense above "
            f"{wrong:.1f} px (2x the median), {(kept > wrong).mean():.4f} published by default: "
            f"{(~np.isfinite(kept[big])).mean():.3f} of them masked; published in the band "
            f"{np.isfinite(kept).mean():.3f}, below it {np.isfinite(masked[band.shape[0]:]).mean():.3f}"
        )
        panel = lambda a: np.where(np.isfinite(a), 128 + np.clip((a - lo) / (hi - lo) * 127, 0, 127), 0)
        gray = 1 + (left.astype(np.float32) * 126 / 255)
        row = np.concatenate([gray, panel(dense), panel(masked)], axis=1)[::2, ::2]
        rows.append(np.round(row).astype(np.uint8))
    write_palette_png(out, np.concatenate(rows, axis=0), pal)


if __name__ == "__main__":
    main()
