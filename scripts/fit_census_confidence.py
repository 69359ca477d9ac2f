#!/usr/bin/env python3
"""Fits the logistic weights of disparity/src/census_confidence.rs on development pairs at 640x480.

    cargo run -p abvs-disparity --example census_confidence_dump -- L R /tmp/dump/NAME
    .deps/python/bin/python3 scripts/fit_census_confidence.py DUMP GT [DUMP GT ...] [--gt-scale S] [--std] [--halves]

GT: a pair's ground truth (PFM, or an 8-bit PNG divided by S; 0 / inf unknown), resampled as
`abvs disparity-eval --resolution 640x480` does. With several pairs each weighs the same (--per pixels drawn
from each; 0, the default, every pixel of a single pair). Prints the weights (the constants B, W_*), then for
each pair the curve of the mask (threshold, density, bad-2 among kept) and bad-2 at a given density. The
shipped weights: Aloe (opencv-doc) alone, the five features. --std adds a sixth (the 3x3 window's standard
deviation of the refined disparity; not shipped, docs/depth.md). --no-curv leaves out the match cost's
curvature (the six-feature model shipped before session 28). --halves ranks the first pair's lower half
by a fit on its upper half (and the other pairs), and the other way round: how the fit generalises within
the real pair. Rendered pairs with ground truth: `cargo run -p abvs-sim --example rendered_pairs -- /tmp/pairs
1 12` (their gt.pfm). Never fit on the held-out Motorcycle."""
import argparse

import numpy as np

from image_io import pfm, png_first_channel

W, H = 640, 480
w, h = 320, 240
NAMES = ["acc", "m", "ln1p(span)", "ln1p(agree)", "cost", "curv", "ln1p(std3)"]  # the last with --std


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


def std3(d):
    """The 3x3 window's standard deviation over its finite values (edges replicated), as the scorer's."""
    ok = np.isfinite(d)
    box = lambda a: sum(np.pad(a, 1, mode="edge")[dy:dy + a.shape[0], dx:dx + a.shape[1]]
                        for dy in range(3) for dx in range(3))
    r = np.where(ok, d, 0).astype(np.float64)
    n = np.maximum(box(ok.astype(np.float64)), 1)
    m = box(r) / n
    return np.sqrt(np.maximum(box(r * r) / n - m * m, 0))


def features(dump):
    f = lambda n, t, s: np.fromfile(f"{dump}/{n}", t).reshape(s)
    stat, refined = f("stat.u8", np.uint8, (h, w)), f("refined.f32", np.float32, (h, w))
    net, prior = f("net.f32", np.float32, (h, w)), f("prior.f32", np.float32, (h, w))
    agree = np.abs(refined - net)
    agree = np.where(np.isfinite(agree), np.minimum(agree, 20), 20)
    x = np.stack([np.isfinite(prior), (stat & 0x7F) / 127.0,
                  np.log1p(span4(refined)), np.log1p(agree),
                  # the engine's own match cost, pooled onto this grid (disparity/src/match_cost.rs)
                  f("cost.f32", np.float32, (h, w)), f("curv.f32", np.float32, (h, w)),
                  np.log1p(std3(refined))], -1).astype(np.float64)
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


def ranked_bad2(conf, good, ok, n, density):
    """bad-2 (%) among the `density` x `n` most confident of the pixels `ok`."""
    order = np.argsort(-conf[ok], kind="stable")
    return 100 * (~good[ok][order][: int(density * n)]).mean()


def main():
    a = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    a.add_argument("pairs", nargs="+", help="DUMP GT, repeated")
    a.add_argument("--gt-scale", type=float, default=1.0)
    a.add_argument("--per", type=int, default=0, help="training pixels drawn from each pair (0: all)")
    a.add_argument("--std", action="store_true", help="the seventh feature")
    a.add_argument("--no-curv", action="store_true", help="without the cost's curvature")
    a.add_argument("--halves", action="store_true", help="the first pair's held-back halves")
    a.add_argument("--density", type=float, default=0.725, help="report bad-2 at this density (SGBM_3WAY's)")
    o = a.parse_args()
    assert len(o.pairs) % 2 == 0, "DUMP GT pairs"
    cols = [0, 1, 2, 3, 4] + ([] if o.no_curv else [5]) + ([6] if o.std else [])
    nf = len(cols)
    names = [NAMES[c] for c in cols]
    data = []
    for dump, gtp in zip(o.pairs[::2], o.pairs[1::2]):
        x, valid, out = features(dump)
        gt = ground_truth(gtp, o.gt_scale)
        known = np.isfinite(gt)
        data.append((dump, x[..., cols], valid, out, known, np.abs(out - gt) <= 2))

    def fit_on(masks):
        rng = np.random.default_rng(1)
        xs, ys = [], []
        for (_, x, valid, out, known, good), m in zip(data, masks):
            i = np.flatnonzero(known & valid & np.isfinite(out) & m)
            if o.per:
                i = rng.choice(i, min(o.per, len(i)), replace=False)
            xs.append(x.reshape(-1, nf)[i])
            ys.append(good.ravel()[i])
        return fit(np.concatenate(xs), np.concatenate(ys).astype(float))

    everywhere = [np.ones((H, W), bool)] * len(data)
    wts, bias = fit_on(everywhere)
    print(f"B = {bias:.4f}; " + "; ".join(f"W[{n}] = {v:.4f}" for n, v in zip(names, wts)))
    for dump, x, valid, out, known, good in data:
        print(dump)
        conf = np.where(valid, 1 / (1 + np.exp(-(x @ wts + bias))), 0)
        n = known.sum()
        for t in np.arange(0.3, 0.96, 0.05):
            kept = known & np.isfinite(out) & (conf >= t)
            print(f"threshold {t:.2f}: density {kept.sum() / n:.3f}, bad-2 among kept {100 * (~good[kept]).mean():.2f} %")
        ok = known & np.isfinite(out) & (conf > 0)
        print(f"bad-2 among the {o.density:.3f} most confident: {ranked_bad2(conf, good, ok, n, o.density):.2f} %")
    if o.halves:
        upper = np.arange(H)[:, None] < H // 2
        for name, train in (("upper", upper), ("lower", ~upper)):
            wts, bias = fit_on([train & np.ones((1, W), bool)] + everywhere[1:])
            _, x, valid, out, known, good = data[0]
            conf = np.where(valid, 1 / (1 + np.exp(-(x @ wts + bias))), 0)
            held = known & ~train
            ok = held & np.isfinite(out) & (conf > 0)
            b = ranked_bad2(conf, good, ok, held.sum(), o.density)
            print(f"fitted on {data[0][0]}'s {name} half: bad-2 among the {o.density:.3f} most confident of the other {b:.2f} %")


if __name__ == "__main__":
    main()
