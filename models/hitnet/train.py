#!/usr/bin/env python3
"""Train a HITNet-style variant on rendered stereo data (PyTorch, CPU, seeded).

  python models/hitnet/gen_data.py --seed 1 --count 2000 --width 320 --height 240 --out models/hitnet/data/train_s
  python models/hitnet/train.py --variant hitnet-s --data models/hitnet/data/train_s --steps 3000 --out models/hitnet/runs/hitnet-s

Prints progress lines (step, loss, EPE, elapsed, ETA), writes checkpoints
(<out>/ckpt.pt every --ckpt-every steps and at the end) and <out>/train.json.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from hitnet import build, n_params, upsample_planes, VARIANTS  # noqa: E402


class Data:
    """One data set directory, or several separated by commas (sampled uniformly over all pairs)."""

    def __init__(self, path):
        self.sets = []
        for p in path.split(","):
            self.sets.append((np.load(os.path.join(p, "left.npy"), mmap_mode="r"),
                              np.load(os.path.join(p, "right.npy"), mmap_mode="r"),
                              np.load(os.path.join(p, "disp.npy"), mmap_mode="r")))
        metas = [json.load(open(os.path.join(p, "meta.json"))) for p in path.split(",")]
        self.meta = metas[0] if len(metas) == 1 else dict(
            seed=[m["seed"] for m in metas], command=" ; ".join(m["command"] for m in metas))
        self.sizes = [len(s[0]) for s in self.sets]
        self.n = sum(self.sizes)
        self.left = self.sets[0][0]

    def get(self, i):
        for (l, r, d), k in zip(self.sets, self.sizes):
            if i < k:
                return l[i], r[i], d[i]
            i -= k

    def batch(self, rng, bs, cw, ch):
        H, W = self.left.shape[1:]
        xs, ds = [], []
        for _ in range(bs):
            i = int(rng.integers(self.n))
            li, ri, di = self.get(i)
            y0 = int(rng.integers(0, H - ch + 1))
            x0 = int(rng.integers(0, W - cw + 1))
            l = li[y0:y0 + ch, x0:x0 + cw].astype(np.float32) / 255
            r = ri[y0:y0 + ch, x0:x0 + cw].astype(np.float32) / 255
            d = di[y0:y0 + ch, x0:x0 + cw].astype(np.float32)
            if rng.random() < 0.5:  # vertical flip keeps rectification
                l, r, d = l[::-1], r[::-1], d[::-1]
            # extra per-eye photometric jitter
            for im in (l, r):
                pass
            g = rng.uniform(0.8, 1.25, size=2)
            gm = rng.uniform(0.85, 1.15, size=2)
            l = np.clip(l * g[0], 0, 1) ** gm[0]
            r = np.clip(r * g[1], 0, 1) ** gm[1]
            xs.append(np.stack([l, r]))
            ds.append(d[None].copy())
        return torch.from_numpy(np.stack(xs).astype(np.float32)), torch.from_numpy(np.stack(ds))


def tile_gt(gt, valid, tile):
    """Mean GT disparity per tile and a mask of tiles that are fully valid and near-planar."""
    vf = valid.float()
    s = F.avg_pool2d(gt * vf, tile)
    c = F.avg_pool2d(vf, tile)
    mean = s / c.clamp(min=1e-6)
    mx = F.max_pool2d(torch.where(valid, gt, torch.full_like(gt, -1e4)), tile)
    mn = -F.max_pool2d(torch.where(valid, -gt, torch.full_like(gt, -1e4)), tile)
    ok = (c > 0.999) & ((mx - mn) < tile * 0.5)
    return mean, ok


def losses(model, x, gt, max_disp, w_init=0.3):
    dfull, cv, outs = model(x, return_all=True)
    valid = (gt > 0) & (gt < max_disp)
    vf = valid.float()
    nval = vf.sum().clamp(min=1)
    err = (dfull - gt).abs()
    l_final = (F.smooth_l1_loss(dfull, gt, reduction="none", beta=1.0) * vf).sum() / nval
    epe = (err * vf).sum() / nval
    # intermediate hypotheses, slanted-plane upsampled to full res
    l_mid = 0.0
    for (d, dx, dy, s) in outs[:-1]:
        du, _, _ = upsample_planes(d, dx, dy, s, s)
        l_mid = l_mid + (F.smooth_l1_loss(du, gt, reduction="none", beta=1.0) * vf).sum() / nval
    l_mid = l_mid / max(len(outs) - 1, 1)
    # init cost volume: cross-entropy with a two-hot target at the tile GT
    tg, ok = tile_gt(gt, valid, model.tile_scale)
    t = (tg / model.init_scale).clamp(0, model.nd - 1.001)
    lo = t.floor().long()
    w_hi = t - lo.float()
    logp = torch.log_softmax(-cv * model.temperature(), 1)
    lp_lo = logp.gather(1, lo)
    lp_hi = logp.gather(1, (lo + 1).clamp(max=model.nd - 1))
    ce = -((1 - w_hi) * lp_lo + w_hi * lp_hi)
    okf = ok.float()
    l_init = (ce * okf).sum() / okf.sum().clamp(min=1)
    loss = l_final + 0.5 * l_mid + w_init * l_init
    return loss, dict(final=l_final.item(), mid=float(l_mid), init=l_init.item(), epe=epe.item())


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--variant", required=True, choices=list(VARIANTS))
    ap.add_argument("--data", required=True)
    ap.add_argument("--arch", default=None, help="architecture config (default = variant)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--crop", type=str, default=None, help="WxH (default: variant specific)")
    ap.add_argument("--lr", type=float, default=2e-3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--init-weight", type=float, default=0.3, help="weight of the init cost-volume cross-entropy")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--ckpt-every", type=int, default=200)
    ap.add_argument("--resume", default=None)
    ap.add_argument("--init-from", default=None,
                    help="checkpoint of a related architecture: equal-shape weights are copied, a 1x1 matching "
                         "projection becomes a (2,1) one (halved per row), a 3x3 update head its centre tap")
    ap.add_argument("--time-limit-min", type=float, default=0,
                    help="wall-clock budget: the lr schedule follows max(step/steps, time/budget) and training stops at the budget")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    cfg = VARIANTS[args.arch or args.variant]
    max_disp = cfg["max_disparity"]
    if args.crop:
        cw, chh = map(int, args.crop.split("x"))
    else:
        cw, chh = (288, 192) if args.variant == "hitnet-s" else (384, 256)
    data = Data(args.data)
    model = build(args.arch or args.variant)
    opt = torch.optim.Adam(model.parameters(), lr=args.lr)

    def lr_at(frac):  # linear warm-up (3%), then cosine to lr/100; frac = progress in [0,1]
        if frac < 0.03:
            return args.lr * (0.1 + 0.9 * frac / 0.03)
        q = (frac - 0.03) / 0.97
        return args.lr * (0.01 + 0.99 * 0.5 * (1 + math.cos(math.pi * min(q, 1.0))))

    if args.init_from:
        src = torch.load(args.init_from, weights_only=False)["model"]
        dst = model.state_dict()
        copied, adapted = 0, []
        for k, v in dst.items():
            if k not in src:
                continue
            w = src[k]
            if w.shape == v.shape:
                dst[k] = w.clone(); copied += 1
            elif w.dim() == 4 and v.dim() == 4 and w.shape[2:] == (1, 1) and v.shape[2:] == (2, 1) and w.shape[:2] == v.shape[:2]:
                dst[k] = w.repeat(1, 1, 2, 1) / 2; adapted.append(k)
            elif w.dim() == 4 and v.dim() == 4 and w.shape[2:] == (3, 3) and v.shape[2:] == (1, 1):
                dst[k] = w[: v.shape[0], :, 1:2, 1:2].clone(); adapted.append(k)
            elif w.dim() == 1 and v.dim() == 1 and w.shape[0] > v.shape[0]:
                dst[k] = w[: v.shape[0]].clone(); adapted.append(k)
        model.load_state_dict(dst)
        print(f"[train] init from {args.init_from}: {copied} tensors copied, adapted {adapted}", flush=True)
    start = 0
    if args.resume:
        ck = torch.load(args.resume, weights_only=False)
        model.load_state_dict(ck["model"])
        opt.load_state_dict(ck["opt"])
        start = ck["step"]
        rng = np.random.default_rng([args.seed, start])
    os.makedirs(args.out, exist_ok=True)
    print(f"[train] {args.variant} params={n_params(model)} crop={cw}x{chh} batch={args.batch} steps={args.steps} "
          f"data={args.data} n={data.n}", flush=True)
    t0 = time.time()
    run = dict(final=0.0, mid=0.0, init=0.0, epe=0.0, loss=0.0)
    nrun = 0
    step = start

    def save(step):
        torch.save(dict(model=model.state_dict(), opt=opt.state_dict(), step=step,
                        variant=args.variant), os.path.join(args.out, "ckpt.pt"))

    for step in range(start + 1, args.steps + 1):
        el = time.time() - t0
        # progress = max(step fraction, wall-time fraction) so the schedule always anneals fully
        frac = (step - 1) / args.steps
        if args.time_limit_min:
            frac = max(frac, el / (args.time_limit_min * 60))
        if frac >= 1.0:
            print(f"[train] time budget reached at step {step - 1}", flush=True)
            step -= 1
            break
        for gparam in opt.param_groups:
            gparam["lr"] = lr_at(frac)
        x, gt = data.batch(rng, args.batch, cw, chh)
        model.train()
        loss, parts = losses(model, x, gt, max_disp, args.init_weight)
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 5.0)
        opt.step()
        for k, v in parts.items():
            run[k] += v
        run["loss"] += loss.item()
        nrun += 1
        el = time.time() - t0
        if step % 25 == 0 or step == args.steps:
            eta = el / (step - start) * (args.steps - step)
            if args.time_limit_min:
                eta = min(eta, args.time_limit_min * 60 - el)
            print(f"[train] step {step}/{args.steps} loss {run['loss']/nrun:.3f} final {run['final']/nrun:.3f} "
                  f"mid {run['mid']/nrun:.3f} init {run['init']/nrun:.3f} EPE {run['epe']/nrun:.3f} "
                  f"lr {opt.param_groups[0]['lr']:.2e} elapsed {el/60:.1f}m ETA {eta/60:.1f}m", flush=True)
            run = {k: 0.0 for k in run}
            nrun = 0
        if step % args.ckpt_every == 0:
            save(step)
    save(step)
    info = dict(variant=args.variant, seed=args.seed, data=data.meta.get("command"), data_seed=data.meta.get("seed"),
                data_count=data.n, crop=f"{cw}x{chh}", batch=args.batch, steps_planned=args.steps, steps_done=step,
                optimizer=f"Adam(lr={args.lr})", init_from=args.init_from, init_weight=args.init_weight, lr_schedule="3% linear warm-up from lr/10, then cosine to lr/100; progress = max(step/steps, elapsed/time_limit)",
                time_limit_min=args.time_limit_min,
                loss="smooth-L1(beta=1) final full-res disparity + 0.5 * mean smooth-L1 of the slanted-plane-upsampled "
                     "intermediate hypotheses (init + every propagation level) + init_weight * cross-entropy of the init tile "
                     "cost volume (softmax(-T*cost), T = 20 or learned) vs two-hot tile GT on fully valid near-planar tiles",
                wall_time_s=round(time.time() - t0, 1), threads=args.threads, torch=torch.__version__,
                command=" ".join(["python", "models/hitnet/train.py"] + sys.argv[1:]))
    if args.resume and os.path.exists(os.path.join(args.out, "train.json")):
        prev = json.load(open(os.path.join(args.out, "train.json")))
        info["wall_time_s"] += prev.get("wall_time_s", 0)
        info["command"] = prev.get("command", "") + " ; " + info["command"]
    json.dump(info, open(os.path.join(args.out, "train.json"), "w"), indent=1)
    print("[train] done", json.dumps(info), flush=True)


if __name__ == "__main__":
    main()
