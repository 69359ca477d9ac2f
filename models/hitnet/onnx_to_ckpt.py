#!/usr/bin/env python3
"""Turn a shipped model.onnx back into a train.py checkpoint (its initializers are the torch parameters).

  python models/hitnet/onnx_to_ckpt.py --onnx models/hitnet/hitnet-s/model.onnx --arch hitnet-s-v4 \
      --out models/hitnet/runs/hitnet-s-shipped/ckpt.pt

Every initializer whose name is a state_dict key of the architecture is copied (match_r shares
match_l's tensor); the script fails if a parameter is missing or has another shape, and checks that
the rebuilt torch model reproduces the ONNX output on a random input.
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


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--onnx", required=True)
    ap.add_argument("--arch", required=True, choices=list(VARIANTS))
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    torch.set_num_threads(1)
    init = {i.name: numpy_helper.to_array(i) for i in onnx.load(args.onnx).graph.initializer}
    model = build(args.arch).eval()
    sd = model.state_dict()
    missing = []
    for name, p in model.named_parameters():
        if name not in init or tuple(init[name].shape) != tuple(p.shape):
            missing.append(name)
            continue
        sd[name] = torch.from_numpy(init[name].copy())
    if missing:
        sys.exit(f"parameters missing / other shape in {args.onnx}: {missing}")
    model.load_state_dict(sd)
    cfg = VARIANTS[args.arch]
    x = torch.rand(1, 2, cfg["height"], cfg["width"])
    sess = ort.InferenceSession(args.onnx, providers=["CPUExecutionProvider"])
    d_onnx = sess.run(None, {"input": x.numpy()})[0]
    with torch.no_grad():
        d_t = model(x).numpy()
    diff = float(np.abs(d_onnx - d_t).max())
    print(f"[onnx_to_ckpt] {len(list(model.parameters()))} parameters copied; torch vs onnx max abs diff {diff:.3g} px")
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    torch.save(dict(model=model.state_dict(), step=0, variant=args.arch, source=args.onnx), args.out)


if __name__ == "__main__":
    main()
