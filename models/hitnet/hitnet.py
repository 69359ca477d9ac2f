"""A small HITNet-style stereo network (Tankovich et al., CVPR 2021), simplified.

Input  [B,2,H,W] float32: channel 0 = left gray, 1 = right gray, in [0,1].
Output [B,1,H,W] float32: left-view disparity in pixels (x_left - x_right).

Pipeline
  1. Shared feature U-Net on left and right (stacked on the batch axis),
     features at 1/2, 1/4, 1/8 (and 1/16 for deeper variants).
  2. Initialisation at the init feature level (1/4 for hitnet-s (v4) and
     hitnet-m (v4, v1), 1/2 for hitnet-s-v3 and older): L1 matching cost between left
     features and right features shifted by every integer disparity of that
     level (one Gather along the outermost axis), cost averaged over 2x2 ->
     tiles (1 tile = 8x8 px at 1/4, 4x4 px at 1/2). Per tile: hard argmin + soft-argmin in a
     +-2 window (sub-pixel, differentiable), slant dx = dy = 0 and a learned
     descriptor from the tile feature and local costs -> tile hypothesis
     h = (d, dx, dy, p).
  3. Propagation/refinement from coarse to fine (down to 1/4 for hitnet-s and
     hitnet-m, 1/2 for the others): at every level the right features are warped by
     the current hypotheses (linear interpolation along x via GatherElements;
     hitnet-s: L1 costs at the 4 integer columns around x - d, interpolated)
     at offsets -1, 0, +1 level-pixels; the local costs + left features +
     hypothesis go through a small residual CNN that predicts residual updates
     (delta d, delta dx, delta dy, delta p). Between levels hypotheses are
     upsampled as slanted planes (d + dx*ox + dy*oy).
  4. Slanted-plane upsampling of the finest hypotheses to full resolution.
Disparities are carried in full-resolution pixels throughout; slants in
disparity-px per full-res px.
"""
from __future__ import annotations

import torch
import torch.nn as nn
import torch.nn.functional as F

VARIANTS = {
    # ch: feature channels at 1/2, 1/4, 1/8, 1/16(, 1/32); init_level: feature level (0 = 1/2) whose
    # features build the init cost volume; tiles are 2x2 of that level. upd: widths of the
    # propagation CNNs from the tile level down to 1/2; upd_blocks: residual blocks each.
    # init_mode "pixel": per-pixel L1 cost of 1x1-projected features at the init level for every
    # integer disparity of that level, averaged over the 2x2 pixels of a tile; "tile" (v0):
    # HITNet's tile features (2x2/s2 conv left, 2x1/(2,1) conv right); "rows": a shared (2,1)/(2,1)
    # projection merges the 2 rows of a tile, cost averaged over its 2 columns.
    # ch[0] = None: no conv at 1/2 (with lcn_half the 2x2-averaged, contrast-normalised input is level 0).
    # lcn_half / lcn_k: LCN window lcn_k on the 2x2-averaged image; finest: finest propagation level
    # (2 = 1/2, 4 = 1/4); fast_up: slanted-plane upsampling as one fixed ConvTranspose; warp "cost":
    # propagation costs from one GatherElements (see Propagation).
    # hitnet-s (shipped) = hitnet-s-v4 below, hitnet-m (shipped) = hitnet-m-v4h below
    # hitnet-m shipped until hitnet-m-v4 (U-Net to 1/32, init at 1/4, propagation at 1/8, 1/4 and 1/2)
    "hitnet-m-v1": dict(width=640, height=480, max_disparity=80, ch=(8, 16, 24, 32, 48), init_level=1,
                        desc=8, upd=(32, 16, 8), upd_blocks=(2, 1, 0), init_mode="pixel", fuse2=True, match_ch=16, lcn=True),
    # hitnet-s shipped until issue 7's fast redesign (init at 1/2 with 21 candidates, propagation at 1/4 and 1/2)
    "hitnet-s-v3": dict(width=320, height=240, max_disparity=40, ch=(8, 12, 24, 32), init_level=0,
                        desc=8, upd=(16, 8), upd_blocks=(1, 0), init_mode="rows", fuse2=True, match_ch=8, lcn=True,
                        light_last=True),
    # hitnet-s as trained in the 08:19 run (1x1 matching projection, full 3x3 update at 1/2)
    "hitnet-s-v2": dict(width=320, height=240, max_disparity=40, ch=(8, 12, 24, 32), init_level=0,
                        desc=8, upd=(16, 8), upd_blocks=(1, 0), init_mode="pixel", fuse2=True, match_ch=8, lcn=True),
    # fast design (issue 7): no 1/2-resolution convs (LCN on the 2x2-averaged image feeds a stride-2 conv to
    # 1/4), init cost volume at 1/4 (11 candidates, 4 px steps, 8x8 px tiles), propagation at 1/8 and 1/4
    # only, the 1/4 slanted planes upsampled x4 to full resolution; plane upsampling as one fixed
    # ConvTranspose, the propagation cost from ONE GatherElements (costs interpolated, not features)
    "hitnet-s-v4": dict(width=320, height=240, max_disparity=40, ch=(None, 12, 24, 32), init_level=1,
                        desc=8, upd=(16, 16), upd_blocks=(1, 1), init_mode="rows", fuse2=True, match_ch=8, lcn=True,
                        light_last=False, lcn_half=True, lcn_k=5, finest=4, fast_up=True, warp="cost"),
    # hitnet-m (v4, issue 7's fast design at 640x480): hitnet-s-v4 with max disparity 80 (init at 1/4 with 21
    # candidates, 0..80 px in 4 px steps; 8x8 px tiles), propagation at 1/8 and 1/4; same tensor shapes as
    # hitnet-s-v4, so it is initialised from the shipped hitnet-s weights
    "hitnet-m-v4": dict(width=640, height=480, max_disparity=80, ch=(None, 12, 24, 32), init_level=1,
                        desc=8, upd=(16, 16), upd_blocks=(1, 1), init_mode="rows", fuse2=True, match_ch=8, lcn=True,
                        light_last=False, lcn_half=True, lcn_k=5, finest=4, fast_up=True, warp="cost"),
    # hitnet-m (shipped): hitnet-m-v4 + a light propagation level at 1/2 on the contrast-normalised input (2 ch,
    # 8-ch update CNN, 1x1 output); its zero-initialised output makes it start as hitnet-m-v4
    "hitnet-m-v4h": dict(width=640, height=480, max_disparity=80, ch=(None, 12, 24, 32), init_level=1,
                         desc=8, upd=(16, 16, 8), upd_blocks=(1, 1, 0), init_mode="rows", fuse2=True, match_ch=8,
                         lcn=True, light_last=True, lcn_half=True, lcn_k=5, finest=2, fast_up=True, warp="cost"),
    # first (weaker) design, kept so its checkpoints stay loadable
    "hitnet-s-v0": dict(width=320, height=240, max_disparity=40, ch=(8, 12, 24, 32), init_level=0,
                        desc=8, upd=(16, 8), upd_blocks=(1, 0)),
}
VARIANTS["hitnet-s"] = dict(VARIANTS["hitnet-s-v4"])
VARIANTS["hitnet-m"] = dict(VARIANTS["hitnet-m-v4h"])


def conv(ci, co, k=3, s=1, d=1, act=True):
    layers = [nn.Conv2d(ci, co, k, s, padding=(k // 2) * d, dilation=d)]
    if act:
        layers.append(nn.LeakyReLU(0.2))
    return nn.Sequential(*layers)


class ResBlock(nn.Module):
    def __init__(self, c, d=1):
        super().__init__()
        self.c1 = nn.Conv2d(c, c, 3, 1, d, d)
        self.c2 = nn.Conv2d(c, c, 3, 1, 1)

    def forward(self, x):
        return F.leaky_relu(x + self.c2(F.leaky_relu(self.c1(x), 0.2)), 0.2)


class FeatureUNet(nn.Module):
    """Encoder to 1/2^(len(ch)), decoder back to 1/2. Returns [f_1/2, f_1/4, ...]."""

    def __init__(self, ch, fuse2=False, cin=1, first_stride=2, dec_min=0):
        super().__init__()
        self.down = nn.ModuleList()
        ci = cin
        for i, c in enumerate(ch):
            if i == 0 and c is None:  # no 1/2-level conv: the (already half-resolution) input is level 0
                self.down.append(nn.Identity())
                continue
            if i == 0:
                self.down.append(conv(ci, c, 3, first_stride))
            else:
                self.down.append(nn.Sequential(conv(ci, c, 3, 2), conv(c, c)))
            ci = c
        self.up = nn.ModuleList()
        self.fuse = nn.ModuleList()
        self.dec_min = dec_min  # finest decoder output level (0 = 1/2); finer levels return encoder features
        for i in range(len(ch) - 1, max(dec_min, 0), -1):
            self.up.append(nn.Sequential(nn.ConvTranspose2d(ch[i], ch[i - 1], 2, 2), nn.LeakyReLU(0.2)))
            self.fuse.append(conv(ch[i - 1], ch[i - 1]) if (i > 1 or fuse2) else nn.Identity())
        self.fuse2 = fuse2

    def forward(self, x):
        skips = []
        for d in self.down:
            x = d(x)
            skips.append(x)
        outs = [x]
        for j, (u, fz) in enumerate(zip(self.up, self.fuse)):
            i = len(skips) - 2 - j
            x = fz(u(x) + skips[i]) if (i > 0 or self.fuse2) else F.leaky_relu(u(x) + skips[i], 0.2)
            outs.append(x)
        outs += skips[: self.dec_min][::-1]
        return outs[::-1]  # finest (1/2) first


def shift_right(fr, d):
    """fr shifted so that out[..., x] = fr[..., x - d] (zero pad)."""
    if d == 0:
        return fr
    return F.pad(fr, (d, 0))[..., : fr.shape[-1]]


def plane_offsets(h, w, factor, device):
    """Offsets (full-res px) of the children centres inside a parent tile.

    factor = upsampling factor; tile_px = parent tile size in full-res px.
    Returns ox [1,1,h*factor,w*factor] (pattern repeating every `factor`)."""
    k = torch.arange(factor, device=device, dtype=torch.float32)
    o = (k - (factor - 1) / 2) / factor  # in units of the parent tile
    ox = o.repeat(w).view(1, 1, 1, w * factor).expand(1, 1, h * factor, w * factor)
    oy = o.repeat(h).view(1, 1, h * factor, 1).expand(1, 1, h * factor, w * factor)
    return ox, oy


def upsample_planes(d, dx, dy, factor, tile_px):
    """Slanted-plane upsampling of hypotheses by `factor` (tile_px = parent tile in full-res px)."""
    h, w = d.shape[-2:]
    ox, oy = plane_offsets(h, w, factor, d.device)
    ox = ox * tile_px
    oy = oy * tile_px
    up = lambda t: F.interpolate(t, scale_factor=factor, mode="nearest")
    dxu, dyu = up(dx), up(dy)
    return up(d) + dxu * ox + dyu * oy, dxu, dyu


def plane_up_weight(factor, tile_px, c_in, c_out):
    """Fixed ConvTranspose2d(k = s = factor) weight doing slanted-plane upsampling in ONE op.

    Input channels (d, dx, dy, p...), output channels = the first c_out of them, nearest-upsampled,
    with d_child = d + dx*ox + dy*oy (same as upsample_planes)."""
    k = torch.arange(factor, dtype=torch.float32)
    o = (k - (factor - 1) / 2) / factor * tile_px
    w = torch.zeros(c_in, c_out, factor, factor)
    for i in range(c_out):
        w[i, i] = 1.0
    w[1, 0] = o.view(1, factor).expand(factor, factor)
    w[2, 0] = o.view(factor, 1).expand(factor, factor)
    return w


class Propagation(nn.Module):
    def __init__(self, cf, p, width, blocks, offsets=(-1.0, 0.0, 1.0), light=False, warp="feat"):
        super().__init__()
        self.offsets = offsets
        # warp "feat": right features linearly interpolated at x - d + o, then L1 (3 costs, 4 GatherElements);
        # "cost": ONE GatherElements of the 4 integer columns around x - d, L1 costs there, costs linearly
        # interpolated to the offsets -1, 0, +1 (fewer ONNX nodes)
        self.warp = warp
        self.light = light  # last level: 1x1 output conv, no descriptor update
        cin = len(offsets) + cf + 3 + p
        self.inp = conv(cin, width)
        self.blocks = nn.Sequential(*[ResBlock(width, d) for d in [1, 2, 1, 2][:blocks]]) if blocks else nn.Identity()
        self.out = nn.Conv2d(width, 3, 1) if light else nn.Conv2d(width, 3 + p, 3, 1, 1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(self, fl, fr, d, dx, dy, p, scale, max_disp):
        """fl, fr [B,C,h,w] at 1/scale; d in full-res px."""
        B, C, h, w = fl.shape
        dl = d / scale  # level px
        if self.warp == "cost":
            return self.forward_cost(fl, fr, d, dx, dy, p, scale, max_disp)
        # warp right features along x by the hypotheses (linear interpolation via GatherElements)
        xs = torch.arange(w, device=fl.device, dtype=torch.float32).view(1, 1, 1, w)
        xr = xs - dl  # [B,1,h,w] sampling position for offset 0
        x0 = torch.floor(xr)
        fr_ = (xr - x0).expand(B, C, h, w)
        g = {}
        for k in (-1, 0, 1, 2):
            idx = (x0 + k).clamp(0, w - 1).long().expand(B, C, h, w)
            g[k] = torch.gather(fr, 3, idx)
        costs = []
        for o in self.offsets:  # sample at xr - o
            k = int(-o)
            wr = g[k] * (1 - fr_) + g[k + 1] * fr_
            costs.append((fl - wr).abs().mean(1, keepdim=True))
        cost = torch.cat(costs, 1)
        return self._update(cost, fl, dl, d, dx, dy, p, scale, max_disp)


    def _update(self, cost, fl, dl, d, dx, dy, p, scale, max_disp):
        """Residual update of the hypotheses from the local costs, the left features and the hypotheses."""
        x = torch.cat([cost, fl, dl / (max_disp / scale), dx, dy, p], 1)
        u = self.out(self.blocks(self.inp(x)))
        d = d + u[:, 0:1] * scale
        dx = dx + u[:, 1:2]
        dy = dy + u[:, 2:3]
        if not self.light:
            p = p + u[:, 3:]
        return d, dx, dy, p

    def forward_cost(self, fl, fr, d, dx, dy, p, scale, max_disp):
        B, C, h, w = fl.shape
        dl = d / scale
        xs = torch.arange(w, device=fl.device, dtype=torch.float32).view(1, 1, 1, 1, w)
        xr = xs - dl.unsqueeze(2)  # [B,1,1,h,w]: sampling position for offset 0
        x0 = torch.floor(xr)
        fr_ = (xr - x0).squeeze(2)  # [B,1,h,w]
        k = torch.arange(2, -2, -1, device=fl.device, dtype=torch.float32).view(1, 1, 4, 1, 1)
        idx = (x0 + k).clamp(0, w - 1).long()  # [B,1,4,h,w]
        idx = idx.permute(0, 1, 3, 2, 4).reshape(B, 1, h, 4 * w).expand(B, C, h, 4 * w)
        g = torch.gather(fr, 3, idx).view(B, C, h, 4, w)
        c = (fl.unsqueeze(3) - g).abs().mean(1).permute(0, 2, 1, 3)  # [B,4,h,w]: costs at x0+2, x0+1, x0, x0-1
        # costs at xr + 1, xr, xr - 1 (offsets -1, 0, +1: same order as the "feat" warp)
        cost = c[:, 1:4] * (1 - fr_) + c[:, 0:3] * fr_
        return self._update(cost, fl, dl, d, dx, dy, p, scale, max_disp)


class HITNetLite(nn.Module):
    def __init__(self, width, height, max_disparity, ch, init_level, desc, upd, upd_blocks, init_mode="tile",
                 fuse2=False, match_ch=16, lcn=False, light_last=False, lcn_half=False, finest=2, lcn_k=7,
                 fast_up=False, warp="feat"):
        super().__init__()
        self.lcn_half = lcn_half  # LCN on the 2x2-averaged image; first conv then has stride 1
        self.lcn_k = lcn_k
        self.finest = finest  # finest propagation level (2 = 1/2, 4 = 1/4); output = its planes upsampled
        self.init_mode = init_mode
        self.lcn = lcn
        self.max_disp = float(max_disparity)
        self.ch = ch
        self.init_level = init_level  # index into feature list (0 = 1/2)
        self.init_scale = 2 ** (init_level + 1)  # feature scale of the init cost volume
        self.tile_scale = self.init_scale * 2  # tiles = 2x2 init-level pixels
        self.nd = int(-(-max_disparity // self.init_scale)) + 1  # integer disparities at init level
        self.feat = FeatureUNet(ch, fuse2, 2 if lcn else 1, first_stride=1 if lcn_half else 2,
                                dec_min=max(min(init_level, {2: 0, 4: 1, 8: 2, 16: 3}[finest]), 1 if ch[0] is None else 0))
        cm = ch[init_level]
        # HITNet-style tile features: left 2x2 stride 2; right 2x1 stride (2,1) keeps the
        # init-level x resolution, so every init-level integer disparity can be tested.
        if init_mode == "tile":
            self.match_l = nn.Conv2d(cm, match_ch, 2, 2)
            self.match_r = nn.Conv2d(cm, match_ch, (2, 1), (2, 1))
        elif init_mode == "rows":
            # shared (2,1)/(2,1) projection: the 2 rows of a tile -> one row, x resolution kept
            self.match_l = nn.Conv2d(cm, match_ch, (2, 1), (2, 1))
            self.match_r = self.match_l
            self.log_temp = nn.Parameter(torch.tensor(3.0))
        else:
            self.match_l = nn.Conv2d(cm, match_ch, 1)
            self.match_r = self.match_l  # shared projection
            self.log_temp = nn.Parameter(torch.tensor(3.0))  # softmax(-exp(log_temp) * cost)
        # larger initial matching features -> a discriminative (non-uniform) init cost volume from the start
        with torch.no_grad():
            self.match_l.weight.mul_(4.0)
            if self.match_r is not self.match_l:
                self.match_r.weight.mul_(4.0)
        self.desc_init = nn.Sequential(conv(ch[init_level + 1] + 5, 16), nn.Conv2d(16, desc, 1))
        # propagation levels: tile level (1/tile_scale) down to 1/2
        self.levels = []
        s = self.tile_scale
        while s >= finest:
            self.levels.append(s)
            s //= 2
        assert len(self.levels) == len(upd), (self.levels, upd)
        self.prop = nn.ModuleList()
        for j, (s, wdt, nb) in enumerate(zip(self.levels, upd, upd_blocks)):
            li = {2: 0, 4: 1, 8: 2, 16: 3}[s]
            cf = ch[li] if ch[li] is not None else (2 if lcn else 1)
            self.prop.append(Propagation(cf, desc, wdt, nb, light=light_last and j == len(upd) - 1, warp=warp))
        self.register_buffer("temp", torch.tensor(1.0))
        self.fast_up = fast_up  # slanted-plane upsampling as one fixed ConvTranspose (fewer ONNX nodes)
        if fast_up:
            for i, s_ in enumerate(self.levels[1:]):
                self.register_buffer(f"upw{i}", plane_up_weight(2, s_ * 2, 3 + desc, 3 + desc), persistent=False)
            self.register_buffer("upw_final", plane_up_weight(self.levels[-1], self.levels[-1], 3, 1), persistent=False)

    def temperature(self):
        return torch.exp(self.log_temp) if self.init_mode in ("pixel", "rows") else 20.0

    def init_hypotheses(self, fl, fr):
        if self.init_mode in ("pixel", "rows"):
            return self.init_pixel(fl, fr)
        ml, mr = self.match_l(fl), self.match_r(fr)  # [B,16,h/2,w/2], [B,16,h/2,w]
        B, C, h, wt = ml.shape
        W2 = mr.shape[-1]
        # all shifted right columns with ONE Gather: column 2x-k of mr (zero column if < 0)
        mrp = F.pad(mr, (1, 0))
        k = torch.arange(self.nd, device=ml.device).view(self.nd, 1)
        x = torch.arange(wt, device=ml.device).view(1, wt)
        idx = (2 * x - k + 1).clamp(min=0).view(-1)
        # gather on the outermost axis (contiguous blocks) -- much faster than on the inner axis
        mrt = mrp.permute(3, 0, 1, 2)  # [W2+1,B,C,h]
        g = torch.index_select(mrt, 0, idx).view(self.nd, wt, B, C, h)
        mlt = ml.permute(3, 0, 1, 2).unsqueeze(0)  # [1,wt,B,C,h]
        cv = (mlt - g).abs().mean(3)  # [nd,wt,B,h]
        return cv.permute(2, 0, 3, 1)  # [B,nd,h,wt] tile cost

    def init_pixel(self, fl, fr):
        ml, mr = self.match_l(fl), self.match_r(fr)  # [B,C,h,w] at the init level
        B, C, h, w = ml.shape
        mrp = F.pad(mr, (1, 0))
        k = torch.arange(self.nd, device=ml.device).view(self.nd, 1)
        x = torch.arange(w, device=ml.device).view(1, w)
        idx = (x - k + 1).clamp(min=0).view(-1)  # column x-k of mr (zero column if < 0)
        g = torch.index_select(mrp.permute(3, 0, 1, 2), 0, idx).view(self.nd, w, B, C, h)
        cv = (ml.permute(3, 0, 1, 2).unsqueeze(0) - g).abs().mean(3)  # [nd,w,B,h]
        cv = cv.permute(2, 0, 3, 1)  # [B,nd,h,w]
        if self.init_mode == "rows":
            return F.avg_pool2d(cv, (1, 2))  # rows already merged: mean over the tile's 2 columns
        return F.avg_pool2d(cv, 2)  # tile cost: mean over the tile's 2x2 init-level pixels

    def forward(self, x, return_all=False):
        B = x.shape[0]
        img = torch.cat([x[:, 0:1], x[:, 1:2]], 0)  # [2B,1,H,W]
        if self.lcn_half:
            img = F.avg_pool2d(img, 2)
        if self.lcn:
            # local contrast normalisation (7x7): invariance to gain / offset / vignetting between the eyes
            k = self.lcn_k
            mu = F.avg_pool2d(img, k, 1, k // 2, count_include_pad=False)
            var = F.avg_pool2d(img * img, k, 1, k // 2, count_include_pad=False) - mu * mu
            xn = (img - mu) / torch.sqrt(F.relu(var) + 4e-4)
            img = torch.cat([xn * 0.25, img - 0.5], 1)
        feats = self.feat(img)
        fl = [f[:B] for f in feats]
        fr = [f[B:] for f in feats]
        cv = self.init_hypotheses(fl[self.init_level], fr[self.init_level])
        # hard argmin + soft-argmin in a +-2 window
        idx = torch.argmin(cv, 1, keepdim=True)
        win = torch.arange(-2, 3, device=x.device).view(1, 5, 1, 1)
        widx = (idx + win).clamp(0, self.nd - 1)
        wc = torch.gather(cv, 1, widx)
        prob = torch.softmax(-wc * self.temperature(), 1)
        d0 = (prob * widx.float()).sum(1, keepdim=True) * self.init_scale
        tile_feat = fl[self.init_level + 1]
        p = self.desc_init(torch.cat([tile_feat, wc], 1))
        dx = torch.zeros_like(d0)
        dy = torch.zeros_like(d0)
        d = d0
        outs = [(d0, dx, dy, self.tile_scale)]
        for i, (s, prop) in enumerate(zip(self.levels, self.prop)):
            if i > 0 and self.fast_up:
                h = F.conv_transpose2d(torch.cat([d, dx, dy, p], 1), getattr(self, f"upw{i - 1}"), stride=2)
                d, dx, dy, p = h[:, 0:1], h[:, 1:2], h[:, 2:3], h[:, 3:]
            elif i > 0:
                d, dx, dy = upsample_planes(d, dx, dy, 2, s * 2)
                p = F.interpolate(p, scale_factor=2, mode="nearest")
            li = {2: 0, 4: 1, 8: 2, 16: 3}[s]
            d, dx, dy, p = prop(fl[li], fr[li], d, dx, dy, p, float(s), self.max_disp)
            outs.append((d, dx, dy, s))
        s = self.levels[-1]
        if self.fast_up:
            dfull = F.conv_transpose2d(torch.cat([d, dx, dy], 1), self.upw_final, stride=s)
        else:
            dfull, _, _ = upsample_planes(d, dx, dy, s, s)
        dfull = F.relu(dfull)
        if return_all:
            return dfull, cv, outs
        return dfull


def build(variant):
    cfg = dict(VARIANTS[variant])
    return HITNetLite(**cfg)


def n_params(m):
    return sum(p.numel() for p in m.parameters())
