#!/usr/bin/env python3
"""Export a trained variant to ONNX, verify it, evaluate it and write the manifest.

  python models/hitnet/evaluate.py --variant hitnet-s --ckpt models/hitnet/runs/hitnet-s/ckpt.pt \
      --heldout models/hitnet/data/heldout_s

Steps
  1. Export to ONNX (opset 17, STATIC input [1,2,H,W], names input / reference_output_disparity),
     run it with onnxruntime and print the max abs difference to the torch output.
  2. Metrics of the ONNX model and of OpenCV StereoSGBM on the held-out rendered set and on the
     Middlebury Aloe pair (opencv-doc), at the variant's resolution.
  3. Latency: median of 50 runs, onnxruntime with intra_op_num_threads=2 vs StereoSGBM
     (cv2 default threads) at the same resolution, measured interleaved.
  4. models/hitnet/<variant>/model.onnx + manifest.json (+ aloe.png visualisation).

Metric definitions (all over pixels with valid GT: GT > 0 and GT < max_disparity):
  EPE = mean |d - gt|; bad-k = % of valid pixels with |d - gt| > k px.
  SGBM: invalid SGBM pixels (no disparity) count as errors for bad-k and are excluded from EPE;
  its valid fraction is reported.

Aloe (Middlebury 2006, in opencv-doc): aloeL.jpg / aloeR.jpg are 1282x1110; aloeGT.png is a
1282x1110 8-bit PNG whose value IS the left disparity in pixels at that full resolution
(scale 1; checked against SGBM: median GT / SGBM-disparity at quarter size = 4.00), 0 = unknown.
For a variant of WxH the images are resized (INTER_AREA, anisotropic: 1282x1110 -> WxH, rows stay
epipolar) and GT disparity is multiplied by W/1282 (nearest-neighbour resize of the GT, 0 kept as
invalid). Aloe disparities reach 211*W/1282 px (52.6 at 320 px, 105 at 640 px), beyond
max_disparity for a few % of pixels: those pixels are reported separately and excluded
("in-range" metrics).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import cv2
import numpy as np
import onnx
import onnxruntime as ort
import torch

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from hitnet import build, n_params, VARIANTS  # noqa: E402

ALOE = "/usr/share/doc/opencv-doc/examples/data"
INPUT_SCALE = 1.0 / 255.0


def metrics(pred, gt, valid, pred_valid=None):
    err = np.abs(pred - gt)
    v = valid
    if pred_valid is None:
        pred_valid = np.ones_like(v)
    pv = v & pred_valid
    nv = max(int(v.sum()), 1)
    out = {
        "epe_px": float(err[pv].mean()) if pv.any() else float("nan"),
        "bad1_pct": float(100 * ((err > 1) | ~pred_valid)[v].sum() / nv),
        "bad2_pct": float(100 * ((err > 2) | ~pred_valid)[v].sum() / nv),
        "bad3_pct": float(100 * ((err > 3) | ~pred_valid)[v].sum() / nv),
        "valid_gt_pixels": int(v.sum()),
    }
    return out, err, pv


def agg(list_of_stats):
    """Pixel-weighted aggregation of per-image sums."""
    tot = {}
    for k in list_of_stats[0]:
        tot[k] = sum(s[k] for s in list_of_stats)
    n = max(tot["n"], 1)
    r = {
        "epe_px": tot["err_sum"] / max(tot["n_pred_valid"], 1),
        "bad1_pct": 100 * tot["b1"] / n, "bad2_pct": 100 * tot["b2"] / n, "bad3_pct": 100 * tot["b3"] / n,
        "valid_gt_pixels": int(tot["n"]),
    }
    return r, tot


def img_stats(pred, gt, valid, pred_valid):
    err = np.abs(pred - gt)
    pv = valid & pred_valid
    bad = lambda k: int((((err > k) | ~pred_valid) & valid).sum())
    return dict(n=int(valid.sum()), n_pred_valid=int(pv.sum()), err_sum=float(err[pv].sum()),
                b1=bad(1), b2=bad(2), b3=bad(3))


def make_sgbm(max_disp):
    nd = int(np.ceil((max_disp + 1) / 16.0) * 16)
    bs = 5
    return cv2.StereoSGBM_create(minDisparity=0, numDisparities=nd, blockSize=bs, P1=8 * bs * bs, P2=32 * bs * bs,
                                 disp12MaxDiff=1, uniquenessRatio=10, speckleWindowSize=100, speckleRange=2), nd


def sgbm_disp(sgbm, l8, r8):
    d = sgbm.compute(l8, r8).astype(np.float32) / 16.0
    valid = d >= 0  # invalid = minDisparity - 1 = -1
    return d, valid


def load_aloe(W, H):
    L = cv2.imread(os.path.join(ALOE, "aloeL.jpg"), cv2.IMREAD_COLOR)
    R = cv2.imread(os.path.join(ALOE, "aloeR.jpg"), cv2.IMREAD_COLOR)
    G = cv2.imread(os.path.join(ALOE, "aloeGT.png"), cv2.IMREAD_UNCHANGED)
    if G.ndim == 3:
        G = G[..., 0]
    W0 = L.shape[1]
    # gray = 0.299 R + 0.587 G + 0.114 B (the contract)
    def gray(im):
        im = cv2.resize(im, (W, H), interpolation=cv2.INTER_AREA).astype(np.float32)
        g = 0.299 * im[..., 2] + 0.587 * im[..., 1] + 0.114 * im[..., 0]
        return np.clip(np.round(g), 0, 255).astype(np.uint8)
    g = cv2.resize(G, (W, H), interpolation=cv2.INTER_NEAREST).astype(np.float32) * (W / W0)
    return gray(L), gray(R), g


def export(model, variant, path):
    cfg = VARIANTS[variant]
    x = torch.rand(1, 2, cfg["height"], cfg["width"])
    torch.onnx.export(model, (x,), path, input_names=["input"], output_names=["reference_output_disparity"],
                      opset_version=17, dynamo=False, do_constant_folding=True)
    m = onnx.load(path)
    onnx.checker.check_model(m)
    return m


def session(path, threads=2):
    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    so.inter_op_num_threads = 1
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    return ort.InferenceSession(path, so, providers=["CPUExecutionProvider"])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--variant", required=True, choices=list(VARIANTS))
    ap.add_argument("--ckpt", required=True)
    ap.add_argument("--arch", default=None, help="architecture config (default = variant)")
    ap.add_argument("--heldout", required=True)
    ap.add_argument("--train-json", default=None)
    ap.add_argument("--out-dir", default=None)
    ap.add_argument("--runs", type=int, default=50)
    args = ap.parse_args()
    torch.set_num_threads(1)
    cfg = VARIANTS[args.variant]
    W, H, MD = cfg["width"], cfg["height"], cfg["max_disparity"]
    out_dir = args.out_dir or os.path.join(HERE, args.variant)
    os.makedirs(out_dir, exist_ok=True)
    model = build(args.arch or args.variant).eval()
    ck = torch.load(args.ckpt, weights_only=False)
    model.load_state_dict(ck["model"])
    onnx_path = os.path.join(out_dir, "model.onnx")
    export(model, args.variant, onnx_path)
    sess = session(onnx_path)

    # ---- held-out rendered set
    hl = np.load(os.path.join(args.heldout, "left.npy"), mmap_mode="r")
    hr = np.load(os.path.join(args.heldout, "right.npy"), mmap_mode="r")
    hd = np.load(os.path.join(args.heldout, "disp.npy"), mmap_mode="r")
    hmeta = json.load(open(os.path.join(args.heldout, "meta.json")))
    assert hl.shape[1:] == (H, W), (hl.shape, H, W)
    sgbm, sgbm_nd = make_sgbm(MD)
    st_net, st_sg = [], []
    sg_valid_frac = []
    maxdiff = 0.0
    ndiff, ntot = 0, 0
    for i in range(len(hl)):
        x = np.stack([hl[i], hr[i]])[None].astype(np.float32) * INPUT_SCALE
        d = sess.run(None, {"input": x})[0][0, 0]
        if i < 3:
            with torch.no_grad():
                dt = model(torch.from_numpy(x)).numpy()[0, 0]
            maxdiff = max(maxdiff, float(np.abs(dt - d).max()))
            ndiff += int((np.abs(dt - d) > 0.01).sum()); ntot += d.size
        gt = hd[i]
        valid = (gt > 0) & (gt < MD)
        st_net.append(img_stats(d, gt, valid, np.ones_like(valid)))
        ds, sv = sgbm_disp(sgbm, np.ascontiguousarray(hl[i]), np.ascontiguousarray(hr[i]))
        st_sg.append(img_stats(ds, gt, valid, sv))
        sg_valid_frac.append(sv[valid].mean())
    held, _ = agg(st_net)
    held_sg, _ = agg(st_sg)
    held_sg["valid_fraction"] = float(np.mean(sg_valid_frac))
    held["images"] = len(hl)
    held["data"] = hmeta["command"]

    # ---- Aloe
    l8, r8, g = load_aloe(W, H)
    x = np.stack([l8, r8])[None].astype(np.float32) * INPUT_SCALE
    d = sess.run(None, {"input": x})[0][0, 0]
    with torch.no_grad():
        dt = model(torch.from_numpy(x)).numpy()[0, 0]
    maxdiff = max(maxdiff, float(np.abs(dt - d).max()))
    ndiff += int((np.abs(dt - d) > 0.01).sum()); ntot += d.size
    diff_frac = ndiff / max(ntot, 1)
    known = g > 0
    valid = known & (g < MD)
    aloe, _ = agg([img_stats(d, g, valid, np.ones_like(valid))])
    aloe["gt_pixels_known"] = int(known.sum())
    aloe["gt_pixels_beyond_max_disparity_excluded"] = int((known & ~valid).sum())
    aloe["gt_disparity_max_at_this_resolution"] = float(g.max())
    aloe["resolution"] = f"{W}x{H} (anisotropic INTER_AREA resize of 1282x1110; GT x {W/1282:.4f})"
    ds, sv = sgbm_disp(sgbm, l8, r8)
    aloe_sg, _ = agg([img_stats(ds, g, valid, sv)])
    aloe_sg["valid_fraction"] = float(sv[valid].mean())
    print(f"[eval] onnx vs torch max abs diff = {maxdiff:.3g} px; pixels differing by > 0.01 px: {100*diff_frac:.4f} %")

    # ---- visualisation
    vis_max = max(float(g.max()), MD)
    col = lambda a: cv2.applyColorMap(np.clip(a / vis_max * 255, 0, 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    dsv = np.where(sv, ds, 0)
    panel = np.hstack([cv2.cvtColor(l8, cv2.COLOR_GRAY2BGR), col(g), col(d), col(dsv)])
    if panel.shape[1] > 1280:  # keep the figure small
        panel = cv2.resize(panel, (panel.shape[1] // 2, panel.shape[0] // 2), interpolation=cv2.INTER_AREA)
    cv2.imwrite(os.path.join(out_dir, "aloe.png"), panel)

    # ---- latency, interleaved
    xl = x.copy()
    t_net, t_sg = [], []
    for _ in range(5):
        sess.run(None, {"input": xl}); sgbm.compute(l8, r8)
    for _ in range(args.runs):
        t = time.perf_counter(); sess.run(None, {"input": xl}); t_net.append(time.perf_counter() - t)
        t = time.perf_counter(); sgbm.compute(l8, r8); t_sg.append(time.perf_counter() - t)
    ms_net = 1000 * float(np.median(t_net))
    ms_sg = 1000 * float(np.median(t_sg))
    try:
        load = os.getloadavg()[0]
    except OSError:
        load = None

    train = None
    tj = args.train_json or os.path.join(os.path.dirname(args.ckpt), "train.json")
    if os.path.exists(tj):
        train = json.load(open(tj))
    r4 = lambda dct: {k: (round(v, 4) if isinstance(v, float) else v) for k, v in dct.items()}
    manifest = {
        "format": "abvs-disparity-model/1",
        "variant": args.variant,
        "file": "model.onnx",
        "input_name": "input",
        "input_layout": "gray2",
        "input_scale": INPUT_SCALE,
        "width": W,
        "height": H,
        "max_disparity": MD,
        "output_name": "reference_output_disparity",
        "opset": 17,
        "parameters": n_params(model),
        "architecture_config": args.arch or args.variant,
        "input_shape": [1, 2, H, W],
        "output_shape": [1, 1, H, W],
        "input_description": "channel 0 = left gray, 1 = right gray (gray = 0.299R+0.587G+0.114B of rectified images) * input_scale",
        "output_description": "left-view disparity in pixels at the input resolution, x_left - x_right (>= 0)",
        "onnx_sha256": __import__("hashlib").sha256(open(onnx_path, "rb").read()).hexdigest(),
        "training": train,
        "metrics": {
            "rendered_heldout": r4(held),
            "aloe": r4(aloe),
            "sgbm_rendered_heldout": r4(held_sg),
            "sgbm_aloe": r4(aloe_sg),
            "onnx_ms_median_2threads": round(ms_net, 2),
            "sgbm_ms_median": round(ms_sg, 2),
            "onnx_vs_torch_max_abs_diff_px": maxdiff,
            "onnx_vs_torch_pct_pixels_diff_gt_0.01px": round(100 * diff_frac, 4),
            "notes": (
                "Valid GT = 0 < gt < max_disparity. EPE = mean abs error; bad-k = % valid pixels with error > k px. "
                "SGBM invalid pixels count as errors for bad-k and are excluded from its EPE. "
                f"SGBM: cv2.StereoSGBM_create(minDisparity=0, numDisparities={sgbm_nd}, blockSize=5, P1=200, P2=800, "
                "disp12MaxDiff=1, uniquenessRatio=10, speckleWindowSize=100, speckleRange=2), mode SGBM, 8-bit gray input. "
                f"Latency: median of {args.runs} runs on the Aloe input, interleaved net/SGBM, onnxruntime "
                f"{ort.__version__} CPU EP intra_op_num_threads=2, cv2 {cv2.__version__} with {cv2.getNumThreads()} threads; "
                f"shared 2-core VM, 1-min load average at measurement {load}."),
        },
    }
    json.dump(manifest, open(os.path.join(out_dir, "manifest.json"), "w"), indent=1)
    print(json.dumps(manifest["metrics"], indent=1))


if __name__ == "__main__":
    main()
