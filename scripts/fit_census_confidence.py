#!/usr/bin/env python3
"""Fits the logistic weights of disparity/src/census_confidence.rs on one development pair at 640x480.

    cargo run -p abvs-disparity --example census_confidence_dump -- L R /tmp/dump
    .deps/python/bin/python3 scripts/fit_census_confidence.py /tmp/dump GT [--gt-scale S]

GT: the pair's ground truth (PFM, or an 8-bit PNG divided by S; 0 / inf unknown), resampled as
`abvs disparity-eval --resolution 640x480` does. Prints the weights (the constants B, W_*), the curve of the
mask (threshold, density, bad-2 among kept) and bad-2 at a given density. Aloe (opencv-doc) was the pair.
Never fit on the held-out Motorcycle."""
import argparse

import numpy as np

from image_io import pfm, png_first_channel

W, H = 640, 480
w, h = 320, 240
NAMES = ["acc", "m", "edge", "ln1p(span)", "ln1p(agree)"]


def ground_truth(path, scale):
    g = pfm(path) if path.lower().endswith(".pfm") else png_first_channel(path).astype(np.float32) / scale
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
