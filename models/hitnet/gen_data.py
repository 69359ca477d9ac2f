#!/usr/bin/env python3
"""Render rectified stereo pairs with exact disparity (seeded, reproducible).

Random 3D scenes (background plane / wall + table, slanted rectangles, boxes,
spheres, thin occluding rods) are ray-cast from BOTH cameras of a rectified
pair (same intrinsics, right camera at x = +baseline), so occlusions are
physical and the ground truth left disparity is exactly f*B/Z of the surface
hit by the left pixel's centre ray.

Surfaces are textured with natural images from the texture pool
(textures.py; Middlebury/KITTI/ETH3D images are excluded), Lambertian shaded
(+ weak view-dependent specular on some objects), then each eye gets its own
optics blur, wide-lens vignetting, gain, gamma, sensor noise and 8-bit
quantisation.

Output: <out>/left.npy, right.npy (uint8 [N,H,W] gray), disp.npy (float32
[N,H,W], 0 = invalid: beyond max_disparity), meta.json.

  python models/hitnet/gen_data.py --seed 1 --count 1500 --width 320 --height 240 --out models/hitnet/data/train_s
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import cv2
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from textures import texture_pool, excluded_reason  # noqa: E402

BASELINE = 0.065  # m
FOCAL_AT_640 = 240.0  # px, rectified focal at 640x480


# ----------------------------------------------------------------- textures
class Textures:
    def __init__(self, files, max_side=512):
        self.files = files
        self.pyr = []
        for f in files:
            assert excluded_reason(f) is None, f
            im = cv2.imread(f, cv2.IMREAD_GRAYSCALE)
            if im is None:
                continue
            s = max_side / max(im.shape)
            if s < 1:
                im = cv2.resize(im, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
            im = im.astype(np.float32) / 255.0
            levels = [im]
            for _ in range(4):
                if min(levels[-1].shape) < 16:
                    break
                levels.append(cv2.pyrDown(levels[-1]))
            self.pyr.append(levels)

    def __len__(self):
        return len(self.pyr)

    def sample(self, idx, level, u, v):
        """Bilinear mirror-repeat lookup; u, v in texels of level 0."""
        levels = self.pyr[idx]
        level = int(min(max(level, 0), len(levels) - 1))
        tex = levels[level]
        h, w = tex.shape
        s = 0.5 ** level
        x = u * s
        y = v * s
        # mirror repeat
        x = np.abs(np.mod(x, 2 * (w - 1)) - (w - 1))
        y = np.abs(np.mod(y, 2 * (h - 1)) - (h - 1))
        x0 = np.floor(x).astype(np.int32)
        y0 = np.floor(y).astype(np.int32)
        x0 = np.clip(x0, 0, w - 2)
        y0 = np.clip(y0, 0, h - 2)
        fx = (x - x0).astype(np.float32)
        fy = (y - y0).astype(np.float32)
        a = tex[y0, x0]
        b = tex[y0, x0 + 1]
        c = tex[y0 + 1, x0]
        d = tex[y0 + 1, x0 + 1]
        return (a * (1 - fx) + b * fx) * (1 - fy) + (c * (1 - fx) + d * fx) * fy


# ----------------------------------------------------------------- geometry
def rand_rotation(rng, max_angle=math.pi):
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    ang = rng.uniform(-max_angle, max_angle)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(ang) * K + (1 - math.cos(ang)) * K @ K


def tilt_normal(rng, base, max_deg):
    """Unit normal tilted from `base` by up to max_deg in a random direction."""
    base = np.asarray(base, np.float64)
    base = base / np.linalg.norm(base)
    t = rng.normal(size=3)
    t -= base * (t @ base)
    t /= np.linalg.norm(t)
    a = math.radians(rng.uniform(0, max_deg))
    return base * math.cos(a) + t * math.sin(a)


def plane_basis(n):
    n = n / np.linalg.norm(n)
    a = np.array([1.0, 0, 0]) if abs(n[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = np.cross(n, a)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    return e1, e2


class Obj:
    """Base: intersect(o, D) -> (t [N], n [N,3], uv [N,2] in metres)."""

    tex = 0
    texel = 0.001  # metres per texel
    contrast = 1.0
    albedo = 0.6
    spec = 0.0
    rot = 0.0


class Plane(Obj):
    def __init__(self, point, n, half=None):
        self.p = np.asarray(point, np.float64)
        self.n = np.asarray(n, np.float64) / np.linalg.norm(n)
        self.e1, self.e2 = plane_basis(self.n)
        self.half = half  # None = infinite, else (a, b) rectangle half sizes
        self.ellipse = False

    def bound(self):
        if self.half is None:
            return None
        return self.p, math.hypot(*self.half)

    def intersect(self, o, D):
        denom = D @ self.n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((self.p - o) @ self.n) / denom
        t = np.where(np.abs(denom) > 1e-9, t, np.inf)
        X = o + D * t[:, None]
        R = X - self.p
        u = R @ self.e1
        v = R @ self.e2
        if self.half is not None:
            a, b = self.half
            if self.ellipse:
                inside = (u / a) ** 2 + (v / b) ** 2 <= 1
            else:
                inside = (np.abs(u) <= a) & (np.abs(v) <= b)
            t = np.where(inside, t, np.inf)
        t = np.where(t > 1e-6, t, np.inf)
        n = np.broadcast_to(self.n, X.shape)
        return t, n, np.stack([u, v], 1)


class Box(Obj):
    def __init__(self, center, R, half):
        self.c = np.asarray(center, np.float64)
        self.R = R  # columns = box axes in camera frame
        self.h = np.asarray(half, np.float64)

    def bound(self):
        return self.c, float(np.linalg.norm(self.h))

    def intersect(self, o, D):
        ol = (o - self.c) @ self.R  # local
        Dl = D @ self.R
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / Dl
            t1 = (-self.h - ol) * inv
            t2 = (self.h - ol) * inv
        tmin = np.minimum(t1, t2)
        tmax = np.maximum(t1, t2)
        tn = np.nanmax(tmin, 1)
        tf = np.nanmin(tmax, 1)
        hit = (tn <= tf) & (tf > 1e-6)
        t = np.where(hit, np.where(tn > 1e-6, tn, tf), np.inf)
        ax = np.argmax(np.nan_to_num(tmin, nan=-np.inf), 1)
        Xl = ol + Dl * np.where(np.isfinite(t), t, 0)[:, None]
        nl = np.zeros_like(Xl)
        idx = np.arange(len(t))
        nl[idx, ax] = np.sign(Xl[idx, ax])
        n = nl @ self.R.T
        # texture coords: the two axes other than the face axis (+ face offset)
        a1 = (ax + 1) % 3
        a2 = (ax + 2) % 3
        u = Xl[idx, a1] + 3.0 * ax
        v = Xl[idx, a2]
        return t, n, np.stack([u, v], 1)


class Sphere(Obj):
    def __init__(self, center, r):
        self.c = np.asarray(center, np.float64)
        self.r = r

    def bound(self):
        return self.c, self.r

    def intersect(self, o, D):
        oc = o - self.c
        a = np.einsum("ij,ij->i", D, D)
        b = 2 * (D @ oc)
        c = oc @ oc - self.r * self.r
        disc = b * b - 4 * a * c
        sq = np.sqrt(np.maximum(disc, 0))
        t0 = (-b - sq) / (2 * a)
        t1 = (-b + sq) / (2 * a)
        t = np.where(t0 > 1e-6, t0, t1)
        t = np.where((disc >= 0) & (t > 1e-6), t, np.inf)
        X = o + D * np.where(np.isfinite(t), t, 0)[:, None]
        n = (X - self.c) / self.r
        u = self.r * np.arctan2(n[:, 0], n[:, 2]) * 2
        v = self.r * np.arcsin(np.clip(n[:, 1], -1, 1)) * 2
        return t, n, np.stack([u, v], 1)


# ----------------------------------------------------------------- scene
def make_scene(rng, W, H, f, ntex, max_disp):
    cx, cy = (W - 1) / 2, (H - 1) / 2
    fb = f * BASELINE
    objs = []

    def set_mat(ob, z_ref, lowtex_p=0.12):
        ob.tex = int(rng.integers(ntex))
        # texel footprint relative to a pixel's footprint at the object's depth
        pix = z_ref / f
        ob.texel = pix * math.exp(rng.uniform(math.log(0.25), math.log(2.5)))
        ob.contrast = rng.uniform(0.05, 0.25) if rng.random() < lowtex_p else rng.uniform(0.6, 1.4)
        ob.albedo = rng.uniform(0.25, 0.9)
        ob.spec = rng.uniform(0.05, 0.35) if rng.random() < 0.25 else 0.0
        ob.shiny = rng.uniform(8, 40)
        ob.rot = rng.uniform(0, 2 * math.pi)
        ob.off = rng.uniform(0, 2000, size=2)
        ob.z_ref = z_ref
        return ob

    # Far fallback (always hit)
    zf = rng.uniform(3.0, 8.0)
    objs.append(set_mat(Plane([0, 0, zf], tilt_normal(rng, [0, 0, -1], 20)), zf))
    # Background: wall, sometimes slanted, sometimes a corner
    kind = rng.random()
    if kind < 0.8:
        zb = rng.uniform(0.9, 2.6)
        objs.append(set_mat(Plane([rng.uniform(-0.3, 0.3), 0, zb], tilt_normal(rng, [0, 0, -1], 60)), zb))
    if kind > 0.5:  # second wall (corner)
        zb = rng.uniform(0.8, 2.0)
        side = rng.choice([-1, 1])
        n = tilt_normal(rng, [-side * 1.0, 0, -0.6], 20)
        objs.append(set_mat(Plane([side * rng.uniform(0.2, 0.6), 0, zb], n), zb))
    # Table / floor (y points down; table below the eyes), strongly slanted
    if rng.random() < 0.75:
        yt = rng.uniform(0.12, 0.6)
        n = tilt_normal(rng, [0, -1, 0], 15)
        objs.append(set_mat(Plane([0, yt, 0.6], n), 0.6))

    def rand_point(zmin, zmax, margin=0.15):
        d = rng.uniform(fb / zmax, fb / zmin)  # uniform in disparity
        z = fb / d
        u = rng.uniform(-margin * W, (1 + margin) * W)
        v = rng.uniform(-margin * H, (1 + margin) * H)
        return np.array([(u - cx) * z / f, (v - cy) * z / f, z])

    zmin_obj = max(fb / (max_disp - 1.0), 0.2)
    nobj = int(rng.integers(3, 13))
    for _ in range(nobj):
        r = rng.random()
        if r < 0.35:  # slanted rectangle / ellipse (cards, books, paper)
            c = rand_point(zmin_obj + 0.03, 1.6)
            size = c[2] * rng.uniform(0.08, 0.6)
            n = tilt_normal(rng, [0, 0, -1], 75)
            ob = Plane(c, n, half=(size * rng.uniform(0.3, 1.0), size * rng.uniform(0.3, 1.0)))
            ob.ellipse = rng.random() < 0.2
        elif r < 0.65:  # box
            c = rand_point(zmin_obj + 0.05, 1.6)
            size = c[2] * rng.uniform(0.05, 0.35)
            half = size * rng.uniform(0.3, 1.0, size=3)
            half = np.minimum(half, (c[2] - zmin_obj) * 0.8)
            ob = Box(c, rand_rotation(rng), half)
        elif r < 0.85:  # sphere
            c = rand_point(zmin_obj + 0.05, 1.6)
            rad = min(c[2] * rng.uniform(0.03, 0.25), (c[2] - zmin_obj) * 0.9)
            ob = Sphere(c, rad)
        else:  # thin occluding rod / pole near the eyes
            c = rand_point(zmin_obj + 0.03, 0.9)
            R = rand_rotation(rng)
            th = c[2] * rng.uniform(0.005, 0.03)
            half = np.array([th, th, c[2] * rng.uniform(0.3, 1.0)])
            half[:2] = np.minimum(half[:2], (c[2] - zmin_obj) * 0.8)
            ob = Box(c, R, half)
        objs.append(set_mat(ob, c[2]))

    # light
    L = np.array([rng.uniform(-1, 1), rng.uniform(-1.2, 0.3), -rng.uniform(0.3, 1.2)])
    L /= np.linalg.norm(L)
    amb = rng.uniform(0.25, 0.6)
    return objs, L, amb


def render_view(objs, L, amb, tex, o, W, H, f, cy_shift=0.0):
    cx, cy = (W - 1) / 2, (H - 1) / 2 + cy_shift
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    D = np.stack([(u.ravel() - cx) / f, (v.ravel() - cy) / f, np.ones(W * H)], 1)
    N = W * H
    tbest = np.full(N, np.inf)
    ibest = np.full(N, -1, np.int32)
    results = []
    Dnorm = np.linalg.norm(D, axis=1)
    for i, ob in enumerate(objs):
        bs = ob.bound() if hasattr(ob, "bound") else None
        if bs is not None:  # bounding-sphere cull: only rays that can hit
            c, rad = bs
            oc = c - o
            cr = np.cross(D, oc)
            sel = np.nonzero(np.linalg.norm(cr, axis=1) <= rad * Dnorm * 1.01)[0]
            t = np.full(N, np.inf)
            n = np.zeros((N, 3))
            uv = np.zeros((N, 2))
            if len(sel):
                ts, ns, uvs = ob.intersect(o, D[sel])
                t[sel], n[sel], uv[sel] = ts, ns, uvs
        else:
            t, n, uv = ob.intersect(o, D)
        closer = t < tbest
        tbest = np.where(closer, t, tbest)
        ibest = np.where(closer, i, ibest)
        results.append((n, uv))
    img = np.zeros(N, np.float32)
    for i, ob in enumerate(objs):
        m = ibest == i
        if not m.any():
            continue
        n, uv = results[i]
        n = n[m]
        uvm = uv[m]
        cr, sr = math.cos(ob.rot), math.sin(ob.rot)
        tu = (cr * uvm[:, 0] - sr * uvm[:, 1]) / ob.texel + ob.off[0]
        tv = (sr * uvm[:, 0] + cr * uvm[:, 1]) / ob.texel + ob.off[1]
        # mip level from the pixel footprint at the hit depth
        foot = tbest[m] / f / ob.texel
        level = int(np.clip(np.round(np.log2(max(np.median(foot), 1e-6))), 0, 4))
        tval = tex.sample(ob.tex, level, tu, tv)
        tval = 0.5 + (tval - tval.mean()) * ob.contrast if len(tval) else tval
        Dm = D[m]
        Dn = Dm / np.linalg.norm(Dm, axis=1, keepdims=True)
        nf = np.where(((n * Dn).sum(1) > 0)[:, None], -n, n)  # face the viewer
        diff = np.maximum(nf @ L, 0) if True else 0
        shade = amb + (1 - amb) * diff
        col = ob.albedo * np.clip(tval, 0, 1.5) * shade
        if ob.spec > 0:
            Hh = L - Dn
            Hh /= np.linalg.norm(Hh, axis=1, keepdims=True)
            col = col + ob.spec * np.maximum((nf * Hh).sum(1), 0) ** ob.shiny
        img[m] = col
    return img.reshape(H, W), tbest.reshape(H, W)


def camera_pipeline(rng, radiance, W, H, params):
    g, gamma, vig, vcx, vcy, blur, noise_a, noise_b = params
    x = radiance
    if blur > 0.05:
        x = cv2.GaussianBlur(x, (0, 0), blur)
    uu, vv = np.meshgrid(np.arange(W), np.arange(H))
    r2 = (((uu - vcx) / (W / 2)) ** 2 + ((vv - vcy) / (W / 2)) ** 2)
    x = x * np.clip(1 - vig * r2 - 0.25 * vig * r2 * r2, 0.05, 1)
    x = x * g
    x = x + rng.normal(size=x.shape) * (noise_a + noise_b * np.sqrt(np.maximum(x, 0)))
    x = np.clip(x, 0, 1) ** gamma
    return np.clip(np.round(x * 255), 0, 255).astype(np.uint8)


def render_pair(rng, tex, W, H, f, max_disp):
    objs, L, amb = make_scene(rng, W, H, f, len(tex), max_disp)
    cy_shift = rng.uniform(-0.3, 0.3) if rng.random() < 0.3 else 0.0
    radL, zL = render_view(objs, L, amb, tex, np.zeros(3), W, H, f)
    radR, _ = render_view(objs, L, amb, tex, np.array([BASELINE, 0, 0]), W, H, f, cy_shift)
    disp = (f * BASELINE / zL).astype(np.float32)
    disp[~np.isfinite(disp) | (disp >= max_disp)] = 0.0
    # auto exposure (shared) + per-eye differences
    expo = rng.uniform(0.6, 1.3) / max(np.percentile(radL, 97), 1e-3)
    base_gamma = rng.uniform(0.7, 1.3)
    base_blur = rng.uniform(0.0, 1.0) * W / 320
    out = []
    for eye in range(2):
        p = (
            expo * (1.0 if eye == 0 else rng.uniform(0.85, 1.15)),
            base_gamma * (1.0 if eye == 0 else rng.uniform(0.92, 1.08)),
            rng.uniform(0.0, 0.4),  # vignetting strength (wide lens)
            W / 2 + rng.uniform(-0.1, 0.1) * W,
            H / 2 + rng.uniform(-0.1, 0.1) * H,
            max(0.0, base_blur + rng.uniform(-0.25, 0.25)),
            rng.uniform(0.002, 0.02),
            rng.uniform(0.0, 0.02),
        )
        out.append(camera_pipeline(rng, radL if eye == 0 else radR, W, H, p))
    return out[0], out[1], disp


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--count", type=int, required=True)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--focal", type=float, default=None, help="px (default 240*width/640)")
    ap.add_argument("--max-disparity", type=float, default=None, help="GT above -> invalid (default width/8)")
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    W, H = args.width, args.height
    f = args.focal or FOCAL_AT_640 * W / 640
    max_disp = args.max_disparity or W / 8
    pool = texture_pool()
    tex = Textures(pool)
    os.makedirs(args.out, exist_ok=True)
    left = np.lib.format.open_memmap(os.path.join(args.out, "left.npy"), "w+", np.uint8, (args.count, H, W))
    right = np.lib.format.open_memmap(os.path.join(args.out, "right.npy"), "w+", np.uint8, (args.count, H, W))
    disp = np.lib.format.open_memmap(os.path.join(args.out, "disp.npy"), "w+", np.float32, (args.count, H, W))
    t0 = time.time()
    for i in range(args.count):
        rng = np.random.default_rng([args.seed, i])  # per-sample stream: reproducible, order-free
        l, r, d = render_pair(rng, tex, W, H, f, max_disp)
        left[i], right[i], disp[i] = l, r, d
        if (i + 1) % 50 == 0 or i + 1 == args.count:
            el = time.time() - t0
            print(f"[gen] {i+1}/{args.count} elapsed {el:.0f}s eta {el/(i+1)*(args.count-i-1):.0f}s", flush=True)
    left.flush(); right.flush(); disp.flush()
    meta = dict(seed=args.seed, count=args.count, width=W, height=H, focal_px=f, baseline_m=BASELINE,
                max_disparity=max_disp, textures=[os.path.basename(p) for p in pool],
                command=" ".join(["python", "models/hitnet/gen_data.py"] + sys.argv[1:]))
    with open(os.path.join(args.out, "meta.json"), "w") as fh:
        json.dump(meta, fh, indent=1)


if __name__ == "__main__":
    main()
