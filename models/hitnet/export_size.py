#!/usr/bin/env python3
"""Re-export a shipped model.onnx at another input size, same weights.

The networks are fully convolutional, but an ONNX export bakes the input size into its reshapes, so a
model runs only at the size it was exported at. The runtime's cost is dominated by the network, and
the network's cost by its input's area: a model exported at 480x360 costs about 0.56x the 640x480 one.

  python models/hitnet/export_size.py --onnx models/hitnet/hitnet-m/model.onnx --arch hitnet-m-v4h \
      --width 512 --height 384 --out /tmp/hitnet-m-512x384.onnx

`--arch` may be a sub-architecture of the source's (`--source-arch`): hitnet-m-v4 is hitnet-m-v4h without its
1/2 propagation level, so the shipped hitnet-m's weights export as the cheaper network whose output is
the 1/4 level's planes (what the runtime's census refinement then refines at full resolution).

Checks, on a textured pair (blurred noise, the right view shifted 20 px): the rebuilt torch model reproduces
the source ONNX at the source's size, and the new export the torch model at the new size, both to 1e-3 px at
the 99.9th percentile. (Random noise is no test: its cost minima tie, and a 1e-6 difference flips a
hypothesis by pixels at a few places: 5.6 px at one pixel of hitnet-m-v4 at 640x480, 1e-4 px on texture.)
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np
import onnx
import onnxruntime as ort
import torch
from onnx import numpy_helper

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from hitnet import build, VARIANTS  # noqa: E402


def load(path, arch):
    init = {i.name: numpy_helper.to_array(i) for i in onnx.load(path).graph.initializer}
    model = build(arch).eval()
    sd = model.state_dict()
    missing = [n for n, p in model.named_parameters() if n not in init or tuple(init[n].shape) != tuple(p.shape)]
    if missing:
        sys.exit(f"{path}: parameters missing / other shape: {missing}")
    for n, _ in model.named_parameters():
        sd[n] = torch.from_numpy(init[n].copy())
    model.load_state_dict(sd)
    return model


def max_diff(path, model, w, h):
    """99.9th percentile of |ONNX - torch| (px) on a textured pair whose disparity is 20 px."""
    base = torch.nn.functional.avg_pool2d(torch.rand(1, 1, h, w + 20), 5, 1, 2)
    x = torch.cat([base[..., :w], base[..., 20:]], 1)
    d = ort.InferenceSession(path, providers=["CPUExecutionProvider"]).run(None, {"input": x.numpy()})[0]
    with torch.no_grad():
        t = model(x).numpy()
    if abs(float(np.median(t)) - 20.0) > 1.0:
        sys.exit(f"{path}: median disparity {np.median(t):.2f} px on a pair shifted by 20 px")
    return float(np.percentile(np.abs(d - t), 99.9))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--onnx", required=True)
    ap.add_argument("--arch", required=True, choices=list(VARIANTS))
    ap.add_argument("--source-arch", default=None, choices=list(VARIANTS), help="the source's (default: --arch)")
    ap.add_argument("--width", type=int, required=True)
    ap.add_argument("--height", type=int, required=True)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    torch.manual_seed(0)
    src_arch = a.source_arch or a.arch
    cfg = VARIANTS[src_arch]
    src = max_diff(a.onnx, load(a.onnx, src_arch), cfg["width"], cfg["height"])
    if src > 1e-3:
        sys.exit(f"{a.onnx}: the rebuilt torch model differs from it by {src:.3g} px")
    model = load(a.onnx, a.arch)
    x = torch.rand(1, 2, a.height, a.width)
    torch.onnx.export(model, (x,), a.out, input_names=["input"], output_names=["reference_output_disparity"],
                      opset_version=17, dynamo=False, do_constant_folding=True)
    onnx.checker.check_model(onnx.load(a.out))
    new = max_diff(a.out, model, a.width, a.height)
    if new > 1e-3:
        sys.exit(f"{a.out}: the export differs from the torch model by {new:.3g} px")
    print(f"[export_size] {a.arch} {a.width}x{a.height} -> {a.out}; torch vs source {src:.2g} px, export vs torch {new:.2g} px")


if __name__ == "__main__":
    main()
