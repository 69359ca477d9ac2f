#!/usr/bin/env python3
"""Fits the logistic weights of disparity/src/census_confidence.rs on one development pair at 640x480.

    cargo run -p abvs-disparity --example census_confidence_dump -- L R /tmp/dump
    .deps/python/bin/python3 scripts/fit_census_confidence.py /tmp/dump GT [--gt-scale S]

GT: the pair's ground truth (PFM, or an 8-bit PNG divided by S; 0 / inf unknown), resampled as
`abvs disparity-eval --resolution 640x480` does. Prints the weights (the constants B, W_*), the curve of the
mask (threshold, density, bad-2 among kept) and bad-2 at a given density. Aloe (opencv-doc) was the pair.
Never fit on the held-out Motorcycle."""
import argparse
import struct
import zlib

import numpy as np

W, H = 640, 480
w, h = 320, 240
NAMES = ["acc", "m", "edge", "ln1p(span)", "ln1p(agree)"]


def png(path):
    """An 8-bit grayscale / RGB / RGBA, non-interlaced PNG (the first channel)."""
    b = open(path, "rb").read()
    pos, idat, hdr = 8, b"", None
    while pos < len(b):
        n, t = struct.unpack(">I4s", b[pos : pos + 8])
        data = b[pos + 8 : pos + 8 + n]
        if t == b"IHDR":
            hdr = struct.unpack(">IIBBBBB", data)
        elif t == b"IDAT":
            idat += data
        pos += 12 + n
    gw, gh, depth, ctype, _, _, inter = hdr
    assert depth == 8 and inter == 0, f"{path}: only 8-bit non-interlaced PNG"
    ch = {0: 1, 2: 3, 4: 2, 6: 4}[ctype]
    raw = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(gh, 1 + gw * ch)
    out = np.zeros((gh, gw * ch), np.int32)
    prev = np.zeros(gw * ch, np.int32)
    for y in range(gh):
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
    return out.reshape(gh, gw, ch)[:, :, 0].astype(np.float32)


def pfm(path):
    b = open(path, "rb").read()
    head = b.split(b"\n", 3)
    gw, gh = map(int, head[1].split())
    return np.frombuffer(head[3][: gw * gh * 4], "<f4").reshape(gh, gw)[::-1].astype(np.float32)


def ground_truth(path, scale):
    g = pfm(path) if path.lower().endswith(".pfm") else png(path) / scale
    g = np.where(np.isfinite(g) & (g > 0), g, np.nan)
    gh, gw = g.shape
    sx = np.float32(W) / np.float32(gw)
    ys = np.minimum(((np.arange(H, dtype=np.float32) + 0.5) * gh / H).astype(int), gh - 1)
    xs = np.minimum(((np.arange(W, dtype=np.float32) + 0.5) / sx).astype(int), gw - 1)
    return g[ys][:, xs] * sx


def span4(d):
    p = np.pad(d, 1, mode="edge")
    lo, hi = d.copy(), d.copy()
    for v in (p[:-2, 1:-1], p[2:, 1:-1], p[1:-1, :-2], p[1:-1, 2:]):
        ok = np.isfinite(v)
        lo, hi = np.where(ok, np.minimum(lo, v), lo), np.where(ok, np.maximum(hi, v), hi)
    return hi - lo


def features(dump):
    f = lambda n, t, s: np.fromfile(f"{dump}/{n}", t).reshape(s)
    stat, refined = f("stat.u8", np.uint8, (h, w)), f("refined.f32", np.float32, (h, w))
    net, prior = f("net.f32", np.float32, (h, w)), f("prior.f32", np.float32, (h, w))
    agree = np.abs(refined - net)
    agree = np.where(np.isfinite(agree), np.minimum(agree, 20), 20)
    x = np.stack([np.isfinite(prior), (stat & 0x7F) / 127.0, (stat & 0x80) > 0,
                  np.log1p(span4(refined)), np.log1p(agree)], -1).astype(np.float64)
    valid = np.isfinite(refined) & (np.arange(w)[None, :] - refined >= 0)
    up = lambda a: np.repeat(np.repeat(a, 2, 0), 2, 1)  # the engine's nearest upsampling
    return up(x), up(valid), f("out640.f32", np.float32, (H, W))


def fit(x, good, l2=1e-3):
    mu, sd = x.mean(0), x.std(0) + 1e-9
    z = np.hstack([(x - mu) / sd, np.ones((len(x), 1))])
    wv = np.zeros(z.shape[1])
    for _ in range(30):  # Newton's method
        p = 1 / (1 + np.exp(-z @ wv))
        g = z.T @ (p - good) / len(z) + l2 * wv
        hs = (z * (p * (1 - p))[:, None]).T @ z / len(z) + l2 * np.eye(len(wv))
        wv -= np.linalg.solve(hs, g)
    return wv[:-1] / sd, wv[-1] - np.sum(wv[:-1] * mu / sd)


def main():
    a = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    a.add_argument("dump")
    a.add_argument("gt")
    a.add_argument("--gt-scale", type=float, default=1.0)
    a.add_argument("--density", type=float, default=0.725, help="report bad-2 at this density (SGBM_3WAY's)")
    o = a.parse_args()
    x, valid, out = features(o.dump)
    gt = ground_truth(o.gt, o.gt_scale)
    known = np.isfinite(gt)
    good = np.abs(out - gt) <= 2
    train = known & valid & np.isfinite(out)
    wts, bias = fit(x[train], good[train].astype(float))
    print(f"B = {bias:.4f}; " + "; ".join(f"W[{n}] = {v:.4f}" for n, v in zip(NAMES, wts)))
    conf = np.where(valid, 1 / (1 + np.exp(-(x @ wts + bias))), 0)
    n = known.sum()
    for t in np.arange(0.3, 0.96, 0.05):
        kept = known & np.isfinite(out) & (conf >= t)
        print(f"threshold {t:.2f}: density {kept.sum() / n:.3f}, bad-2 among kept {100 * (~good[kept]).mean():.2f} %")
    ok = known & np.isfinite(out) & (conf > 0)
    order = np.argsort(-conf[ok], kind="stable")
    k = int(o.density * n)
    print(f"bad-2 among the {o.density:.3f} most confident: {100 * (~good[ok][order][:k]).mean():.2f} %")


if __name__ == "__main__":
    main()
