#!/usr/bin/env python3
"""Independent data generator for the SPM eye calibration discrepancy workflow.

Written from shared/spec (conventions.md, dataset.md, effects.md) and
shared/reference/paper.md ONLY; no project source was read.  See README.md.

    python3 generate.py --out data            # writes data/{dev,final}/*.csv + truth.json

Deterministic: re-running reproduces every file byte for byte.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import numpy as np

# --------------------------------------------------------------------------------------
# Constants of the nominal eye (conventions.md)
# --------------------------------------------------------------------------------------
COUNTS_PER_REV = 92672
DEG_PER_COUNT = 360.0 / COUNTS_PER_REV
D1_NOM = 60.0
D2_NOM = 90.0
PSI = (90.0, 210.0, 330.0)
RAD = math.pi / 180.0
DEG = 180.0 / math.pi

# Collection protocol
GRID_ALPHA = np.arange(-30, 31, 3, dtype=float)  # 21
GRID_BETA = np.arange(-15, 16, 3, dtype=float)  # 11
GRID_GAMMA = np.arange(-30, 31, 3, dtype=float)  # 21
SAMPLE_PERIOD_S = 0.2
NOISE_ROT_DEG = 0.01  # per rotation axis, 1 sigma
NOISE_POS_MM = 0.05  # per position axis, 1 sigma
GRAVITY = (0.0, 1.0, 0.0)  # base frame, head upright

# Encoder read heads (hidden-effect model, see README)
READ_RADIUS_MM = 15.0
HEAD_WHEEL_ANGLE_DEG = PSI  # wheel angle under head i when link i is at true angle 0
HOMING_LAST_MOTION = (0.0, 0.0, 1.0)  # start-up roll ends moving in +roll (+z)

FAMILY_SEEDS = {"dev": 271828, "final": 314159, "dev2": 161803, "final2": 577215, "dev3": 141421,
                "final3": 662607}

# (set name, hidden effects in effects.md vocabulary / "outside:ripple3")
SETS = [
    ("null", []),
    ("input_axis_tilt", ["input_axis_tilt"]),
    ("code_wheel_eccentricity", ["code_wheel_eccentricity"]),
    ("encoder_scale", ["encoder_scale"]),
    ("hinge_backlash", ["hinge_backlash"]),
    ("gravity_sag", ["gravity_sag"]),
    ("link_angle_error_hidden", ["link_angle_error"]),
    ("eccentricity_plus_sag", ["code_wheel_eccentricity", "gravity_sag"]),
    ("backlash_plus_tilt", ["hinge_backlash", "input_axis_tilt"]),
    ("ripple3", ["outside:ripple3"]),
    ("scale_plus_eccentricity", ["encoder_scale", "code_wheel_eccentricity"]),
]

# Round 2 (families dev2 / final2): larger outside ripples of any cycle count, backlash in each
# link's reading (a lag of each link behind its last motion), sizes beyond effects.md's range and
# three effects together. "outside:ripple" is a reading ripple of one link with a drawn cycle count.
SETS2 = [
    ("ripple_large", ["outside:ripple"]),
    ("link_backlash", ["hinge_backlash"]),
    ("scale_beyond_range", ["encoder_scale"]),
    ("scale_plus_eccentricity", ["encoder_scale", "code_wheel_eccentricity"]),
    ("tilt_eccentricity_sag", ["input_axis_tilt", "code_wheel_eccentricity", "gravity_sag"]),
    ("backlash_scale_tilt", ["hinge_backlash", "encoder_scale", "input_axis_tilt"]),
    ("ripple_plus_tilt", ["outside:ripple", "input_axis_tilt"]),
]


# Round 3 (families dev3 / final3): backlash as a settling of the platform about each leg's hinge,
# a ripple with its second harmonic, a slow drift of the measured orientation over the session,
# three effects with the hinge form, and a library effect under a drift.
SETS3 = [
    ("hinge_backlash_at_hinges", ["hinge_backlash"]),
    ("ripple_with_harmonic", ["outside:ripple_harmonic"]),
    ("drift", ["outside:drift"]),
    ("hinge_backlash_eccentricity_sag", ["hinge_backlash", "code_wheel_eccentricity", "gravity_sag"]),
    ("scale_under_drift", ["encoder_scale", "outside:drift"]),
]


def round_of(family):
    return 3 if family.endswith("3") else 2 if family.endswith("2") else 1


def sets_of(family):
    return {1: SETS, 2: SETS2, 3: SETS3}[round_of(family)]


GEOM_MAX_ROT_DEG = 1.5  # bound on the deviation of a unit's mechanism from nominal
GEOM_MAX_POS_MM = 4.0


# --------------------------------------------------------------------------------------
# Rotation helpers (numpy, batched over a leading axis where useful)
# --------------------------------------------------------------------------------------
def rotvec_to_R(v):
    """Rodrigues; v (...,3) in rad -> (...,3,3)."""
    v = np.asarray(v, dtype=float)
    th = np.linalg.norm(v, axis=-1)[..., None, None]
    K = np.zeros(v.shape[:-1] + (3, 3))
    K[..., 0, 1] = -v[..., 2]
    K[..., 0, 2] = v[..., 1]
    K[..., 1, 0] = v[..., 2]
    K[..., 1, 2] = -v[..., 0]
    K[..., 2, 0] = -v[..., 1]
    K[..., 2, 1] = v[..., 0]
    small = th < 1e-8
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th**2 / 6.0, np.sin(ths) / ths)
    b = np.where(small, 0.5 - th**2 / 24.0, (1.0 - np.cos(ths)) / ths**2)
    return np.eye(3) + a * K + b * (K @ K)


def R_to_rotvec(R):
    """(...,3,3) -> (...,3) rad (angles well below pi)."""
    R = np.asarray(R, dtype=float)
    w = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                  R[..., 1, 0] - R[..., 0, 1]], axis=-1)
    s = 0.5 * np.linalg.norm(w, axis=-1)
    c = 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0)
    th = np.arctan2(s, c)
    f = np.where(s < 1e-12, 0.5, th / (2.0 * np.where(s < 1e-12, 1.0, s)))
    return w * f[..., None]


def rot_angle_deg(R):
    """Rotation angle (deg) of (...,3,3) rotation matrices."""
    return np.linalg.norm(R_to_rotvec(R), axis=-1) * DEG


def Rx(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def Ry(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def Rz(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def fick_to_R(alpha_deg, beta_deg, gamma_deg):
    """R = Ry(gamma) Rx(alpha) Rz(beta) (conventions.md)."""
    a = np.asarray(alpha_deg, float) * RAD
    b = np.asarray(beta_deg, float) * RAD
    g = np.asarray(gamma_deg, float) * RAD
    return Ry(g) @ Rx(a) @ Rz(b)


def R_to_fick(R):
    """Inverse of fick_to_R; returns (...,3) [alpha, beta, gamma] in deg."""
    R = np.asarray(R, float)
    alpha = np.arctan2(-R[..., 1, 2], np.hypot(R[..., 1, 0], R[..., 1, 1]))
    beta = np.arctan2(R[..., 1, 0], R[..., 1, 1])
    gamma = np.arctan2(R[..., 0, 2], R[..., 2, 2])
    return np.stack([alpha, beta, gamma], -1) * DEG


def wrap_deg(x):
    return (np.asarray(x) + 180.0) % 360.0 - 180.0


# --------------------------------------------------------------------------------------
# Command grid (serpentine) and nominal inverse kinematics
# --------------------------------------------------------------------------------------
def serpentine_grid():
    """Commanded poses [alpha, beta, gamma] (deg) in boustrophedon order.

    Outer loop alpha (ascending), middle gamma (direction alternates), inner beta
    (direction alternates at every inner sweep), so consecutive samples differ by
    one 3-deg step in exactly one axis.
    """
    rows = []
    gdir = 1
    bdir = 1
    for a in GRID_ALPHA:
        gs = GRID_GAMMA if gdir > 0 else GRID_GAMMA[::-1]
        for g in gs:
            bs = GRID_BETA if bdir > 0 else GRID_BETA[::-1]
            for b in bs:
                rows.append((a, b, g))
            bdir = -bdir
        gdir = -gdir
    return np.array(rows, dtype=float)


def _nominal_v0():
    return np.array([[math.cos((p + 90.0) * RAD), math.sin((p + 90.0) * RAD), 0.0] for p in PSI])


def nominal_ik_roots(R):
    """Both closed-form roots theta_i (deg) of w_i(theta).(R v_i0) = cos d2 (nominal eye).

    R: (N,3,3). Returns (N,3,2) in (-180,180]; NaN where no real root.
    With phi = psi + theta: s1 (vx cos phi + vy sin phi) - c1 vz = c2, i.e.
    rho cos(phi - mu) = C with mu = atan2(vy, vx), rho = s1 |v_xy|, C = c2 + c1 vz.
    """
    v = np.einsum("nab,ib->nia", R, _nominal_v0())  # (N,3,3)
    s1, c1, c2 = math.sin(D1_NOM * RAD), math.cos(D1_NOM * RAD), math.cos(D2_NOM * RAD)
    rho = s1 * np.hypot(v[..., 0], v[..., 1])
    mu = np.arctan2(v[..., 1], v[..., 0])
    C = c2 + c1 * v[..., 2]
    with np.errstate(invalid="ignore"):
        d = np.arccos(C / rho)
    psi = np.array(PSI) * RAD
    r_minus = wrap_deg((mu - d - psi) * DEG)
    r_plus = wrap_deg((mu + d - psi) * DEG)
    return np.stack([r_minus, r_plus], -1)


def nominal_ik_track(R, theta_start=(0.0, 0.0, 0.0)):
    """Working-mode IK along a path: per leg the root nearest the previous sample's angle
    (starting at home, theta = 0)."""
    roots = nominal_ik_roots(R)
    n = roots.shape[0]
    out = np.empty((n, 3))
    prev = np.array(theta_start, float)
    for k in range(n):
        r = roots[k]
        dist = np.abs(wrap_deg(r - prev[:, None]))
        dist = np.where(np.isnan(dist), np.inf, dist)
        pick = np.argmin(dist, axis=1)
        th = r[np.arange(3), pick]
        th = prev + wrap_deg(th - prev)  # unwrap
        out[k] = th
        prev = th
    return out


# --------------------------------------------------------------------------------------
# Mechanism model (geometric effects + input_axis_tilt) and forward kinematics
# --------------------------------------------------------------------------------------
def axis_tilt_matrix(tilt_deg, dir_deg):
    """Rotation taking +z to the axis tilted by tilt_deg toward azimuth dir_deg (about z x a)."""
    t = tilt_deg * RAD
    d = dir_deg * RAD
    return rotvec_to_R(np.array([-math.sin(d) * t, math.cos(d) * t, 0.0]))


class Mechanism:
    """Per-leg geometry of one (possibly deviated) coaxial SPM.

    leg i:  w_i(theta) = Q_i . [sin d1_i cos(psi_i+theta), sin d1_i sin(psi_i+theta), -cos d1_i]
            platform axis at orientation R: R v_i0
            loop closure: w_i(theta_i) . (R v_i0) = cos d2_i
    Q_i is the input-axis tilt (identity when the axis is coaxial); theta is the TRUE link angle.
    All axes pass through O1, so the platform only rotates about O1.
    """

    def __init__(self, d1_deg, d2_deg, v0, Q):
        self.d1 = [float(x) for x in d1_deg]
        self.d2 = [float(x) for x in d2_deg]
        self.v0 = [tuple(float(c) for c in row) for row in np.asarray(v0)]
        self.Q = [tuple(tuple(float(c) for c in r) for r in q) for q in np.asarray(Q)]
        self.sd1 = [math.sin(d * RAD) for d in self.d1]
        self.cd1 = [math.cos(d * RAD) for d in self.d1]
        self.cd2 = [math.cos(d * RAD) for d in self.d2]
        self.psi = [p * RAD for p in PSI]
        self.Qnp = np.asarray(Q, float)
        self.v0np = np.asarray(v0, float)

    @staticmethod
    def nominal():
        return Mechanism([D1_NOM] * 3, [D2_NOM] * 3, _nominal_v0(), np.stack([np.eye(3)] * 3))

    def w(self, i, theta_rad):
        ph = self.psi[i] + theta_rad
        s, c = self.sd1[i], self.cd1[i]
        l0, l1, l2 = s * math.cos(ph), s * math.sin(ph), -c
        q = self.Q[i]
        return (q[0][0] * l0 + q[0][1] * l1 + q[0][2] * l2,
                q[1][0] * l0 + q[1][1] * l1 + q[1][2] * l2,
                q[2][0] * l0 + q[2][1] * l1 + q[2][2] * l2)

    def w_batch(self, theta_deg):
        """theta_deg (N,3) -> w (N,3,3) [sample, leg, xyz]."""
        ph = np.array(self.psi)[None, :] + np.asarray(theta_deg) * RAD
        sd1 = np.array(self.sd1)[None, :]
        loc = np.stack([sd1 * np.cos(ph), sd1 * np.sin(ph), -np.broadcast_to(np.array(self.cd1), ph.shape)], -1)
        return np.einsum("iab,nib->nia", self.Qnp, loc)

    def residual_batch(self, theta_deg, R):
        w = self.w_batch(theta_deg)
        v = np.einsum("nab,ib->nia", R, self.v0np)
        return np.einsum("nia,nia->ni", w, v) - np.array(self.cd2)[None, :]

    # ---- scalar Newton (pure Python: fast for 3x3 and sequential warm starts) ----
    def fk_newton(self, theta_deg, R0, tol=1e-14, max_iter=30):
        """Newton on the three loop-closure equations for R, starting at R0 (3x3 nested
        tuples/lists). Update R <- exp([delta]) R with J_i = (R v_i0) x w_i."""
        R = _orthonormalize(R0)
        ws = [self.w(i, theta_deg[i] * RAD) for i in range(3)]
        for it in range(max_iter):
            f = []
            J = []
            for i in range(3):
                v = self.v0[i]
                rv = (R[0][0] * v[0] + R[0][1] * v[1] + R[0][2] * v[2],
                      R[1][0] * v[0] + R[1][1] * v[1] + R[1][2] * v[2],
                      R[2][0] * v[0] + R[2][1] * v[1] + R[2][2] * v[2])
                w = ws[i]
                f.append(w[0] * rv[0] + w[1] * rv[1] + w[2] * rv[2] - self.cd2[i])
                J.append((rv[1] * w[2] - rv[2] * w[1], rv[2] * w[0] - rv[0] * w[2], rv[0] * w[1] - rv[1] * w[0]))
            if max(abs(f[0]), abs(f[1]), abs(f[2])) < tol:
                return R, it, True
            d = _solve3(J, (-f[0], -f[1], -f[2]))
            if d is None:
                return R, it, False
            R = _matmul(_expm_small(d), R)
        fin = max(abs(x) for x in f)
        return R, max_iter, fin < 1e-11

    def fk_track(self, thetas_deg, R_start=None, theta_start=None, max_step_deg=4.0):
        """Sequential FK along a path: each sample warm-started from the previous sample's
        solution (identity at home). Large jumps are split into sub-steps (continuation).
        Returns R (N,3,3) and a bool mask of solved samples."""
        n = len(thetas_deg)
        out = np.empty((n, 3, 3))
        ok = np.ones(n, bool)
        R = R_start if R_start is not None else ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
        prev = np.zeros(3) if theta_start is None else np.asarray(theta_start, float)
        for k in range(n):
            th = np.asarray(thetas_deg[k], float)
            nsub = max(1, int(math.ceil(np.max(np.abs(th - prev)) / max_step_deg)))
            good = True
            Rk = R
            for s in range(1, nsub + 1):
                ths = prev + (th - prev) * (s / nsub)
                Rk, _, good = self.fk_newton(ths.tolist(), Rk)
                if not good:
                    break
            if good:
                R = Rk
                prev = th
                out[k] = np.array(R)
            else:
                ok[k] = False
                out[k] = np.nan
        return out, ok

    def fk_batch(self, thetas_deg, R_init, tol=1e-14, max_iter=30):
        """Vectorised Newton (used as a cross-check of the sequential solver)."""
        R = np.array(R_init, float)
        th = np.asarray(thetas_deg, float)
        w = self.w_batch(th)
        for _ in range(max_iter):
            v = np.einsum("nab,ib->nia", R, self.v0np)
            f = np.einsum("nia,nia->ni", w, v) - np.array(self.cd2)[None, :]
            if np.max(np.abs(f)) < tol:
                break
            J = np.cross(v, w)
            d = np.linalg.solve(J, -f[..., None])[..., 0]
            R = rotvec_to_R(d) @ R
        return R


def _orthonormalize(R):
    a = R[0]
    b = R[1]
    na = math.sqrt(a[0] ** 2 + a[1] ** 2 + a[2] ** 2)
    a = (a[0] / na, a[1] / na, a[2] / na)
    d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    b = (b[0] - d * a[0], b[1] - d * a[1], b[2] - d * a[2])
    nb = math.sqrt(b[0] ** 2 + b[1] ** 2 + b[2] ** 2)
    b = (b[0] / nb, b[1] / nb, b[2] / nb)
    c = (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])
    return (a, b, c)


def _solve3(J, r):
    (a, b, c), (d, e, f), (g, h, i) = J
    A = e * i - f * h
    B = -(d * i - f * g)
    C = d * h - e * g
    det = a * A + b * B + c * C
    if abs(det) < 1e-12:
        return None
    inv = ((A, -(b * i - c * h), b * f - c * e),
           (B, a * i - c * g, -(a * f - c * d)),
           (C, -(a * h - b * g), a * e - b * d))
    return tuple((inv[k][0] * r[0] + inv[k][1] * r[1] + inv[k][2] * r[2]) / det for k in range(3))


def _expm_small(v):
    x, y, z = v
    th2 = x * x + y * y + z * z
    if th2 < 1e-16:
        a = 1.0 - th2 / 6.0
        b = 0.5 - th2 / 24.0
    else:
        th = math.sqrt(th2)
        a = math.sin(th) / th
        b = (1.0 - math.cos(th)) / th2
    return ((1.0 - b * (y * y + z * z), -a * z + b * x * y, a * y + b * x * z),
            (a * z + b * x * y, 1.0 - b * (x * x + z * z), -a * x + b * y * z),
            (-a * y + b * x * z, a * x + b * y * z, 1.0 - b * (x * x + y * y)))


def _matmul(A, B):
    return tuple(tuple(A[r][0] * B[0][c] + A[r][1] * B[1][c] + A[r][2] * B[2][c] for c in range(3)) for r in range(3))


# --------------------------------------------------------------------------------------
# A unit: parameters, encoder model, platform effects, camera
# --------------------------------------------------------------------------------------
def _signed_uniform(rng, lo, hi, size=None):
    mag = rng.uniform(lo, hi, size)
    sgn = np.where(rng.uniform(0.0, 1.0, size) < 0.5, -1.0, 1.0)
    return mag * sgn


def _random_unit(rng):
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def draw_geometry(rng, force_big_link_error=False):
    g = {}
    g["encoder_zero_offset_deg"] = _signed_uniform(rng, 0.1, 1.0, 3)
    g["d1_error_deg"] = _signed_uniform(rng, 0.1, 0.5, 3)
    g["d2_error_deg"] = _signed_uniform(rng, 0.1, 0.5, 3)
    if force_big_link_error:
        k = int(rng.integers(0, 6))
        val = float(_signed_uniform(rng, 0.3, 0.5))
        (g["d1_error_deg"] if k < 3 else g["d2_error_deg"])[k % 3] = val
    mag = rng.uniform(0.1, 0.5, 3)
    dirn = rng.uniform(0.0, 2.0 * math.pi, 3)
    g["platform_axis_azimuth_error_deg"] = mag * np.cos(dirn)
    g["platform_axis_elevation_error_deg"] = mag * np.sin(dirn)
    ang = rng.uniform(0.5, 3.0)
    g["camera_rotvec_deg"] = _random_unit(rng) * ang
    off = rng.uniform(2.0, 5.0)
    g["camera_offset_mm"] = _random_unit(rng) * off
    return g


def draw_hidden(rng):
    """Draw every hidden effect's parameters (the set decides which are switched on)."""
    h = {}
    # input_axis_tilt: 1..3 legs tilted, upper half of 0.05-0.3 deg
    nt = int(rng.integers(1, 4))
    legs = sorted(int(x) for x in rng.permutation(3)[:nt])
    tilt = np.zeros(3)
    tdir = np.zeros(3)
    for i in legs:
        tilt[i] = rng.uniform(0.175, 0.3)
        tdir[i] = rng.uniform(0.0, 360.0)
    h["input_axis_tilt"] = {"tilt_deg": tilt, "tilt_direction_deg": tdir}
    # code_wheel_eccentricity: e 22-30 um, direction kappa
    e = rng.uniform(22.0, 30.0)
    kappa = rng.uniform(0.0, 360.0)
    h["code_wheel_eccentricity"] = {"e_um": e, "direction_deg": kappa}
    # encoder_scale: relative 5.5e-4 .. 1e-3, either sign, common to all links
    h["encoder_scale"] = {"relative": float(_signed_uniform(rng, 5.5e-4, 1e-3))}
    # hinge_backlash (platform lag) 0.06-0.1 deg
    h["hinge_backlash"] = {"lag_deg": rng.uniform(0.06, 0.1)}
    # gravity_sag: peak 0.07-0.1 deg, CoM 8-12 mm in front of O1 along the optical axis
    h["gravity_sag"] = {"peak_deg_target": rng.uniform(0.07, 0.1), "com_distance_mm": rng.uniform(8.0, 12.0)}
    # outside:ripple3
    h["outside:ripple3"] = {"link": int(rng.integers(0, 3)) + 1, "amplitude_deg": rng.uniform(0.045, 0.055),
                            "phase_deg": rng.uniform(0.0, 360.0)}
    return h


def draw_hidden2(rng, name):
    """Round 2: the round-1 draws, then the larger / other forms (drawn after, so the stream of
    the round-1 parameters is the same function of the seed)."""
    h = draw_hidden(rng)
    # backlash in each reading: each link settles behind its last motion by half its clearance
    h["hinge_backlash"] = {"model": "link_lag", "clearance_deg": rng.uniform(0.04, 0.06, 3)}
    # a reading ripple of 2..6 cycles per revolution, 0.1-0.15 deg (up to 3x the round-1 size)
    h["outside:ripple"] = {"link": int(rng.integers(0, 3)) + 1, "cycles": int(rng.integers(2, 7)),
                           "amplitude_deg": rng.uniform(0.1, 0.15), "phase_deg": rng.uniform(0.0, 360.0)}
    if name == "scale_beyond_range":
        # 2-3x the top of effects.md's 1e-4 - 1e-3
        h["encoder_scale"] = {"relative": float(_signed_uniform(rng, 2.0e-3, 3.0e-3))}
    return h


def draw_hidden3(rng, name):
    """Round 3: the round-2 draws, then the round-3 forms (drawn after, as round 2 does)."""
    h = draw_hidden2(rng, name)
    # effects.md: "the platform settles differently depending on the direction from which each link
    # last approached". Read at the platform: the clearance of leg i's hinge on the platform lets the
    # platform turn about that hinge's axis, to the side link i last pushed from.
    h["hinge_backlash"] = {"model": "hinge_lag", "clearance_deg": rng.uniform(0.05, 0.08, 3)}
    # a ripple of k cycles (2..5) with its second harmonic (2k cycles), e.g. a polygonal hub
    h["outside:ripple_harmonic"] = {"link": int(rng.integers(0, 3)) + 1, "cycles": int(rng.integers(2, 6)),
                                    "amplitude_deg": rng.uniform(0.08, 0.12), "phase_deg": rng.uniform(0.0, 360.0),
                                    "harmonic_amplitude_deg": rng.uniform(0.04, 0.06),
                                    "harmonic_phase_deg": rng.uniform(0.0, 360.0)}
    # the measured orientation drifts linearly over the session (board or head warming up)
    h["outside:drift"] = {"end_deg": rng.uniform(0.06, 0.1), "axis": _random_unit(rng)}
    return h


class Unit:
    def __init__(self, geom, hidden_params, on):
        self.g = geom
        self.h = hidden_params
        self.on = set(on)

    # ---- mechanism ----
    def mechanism(self, link_errors=True, tilt=None):
        g = self.g
        d1 = D1_NOM + (g["d1_error_deg"] if link_errors else np.zeros(3))
        d2 = D2_NOM + (g["d2_error_deg"] if link_errors else np.zeros(3))
        az = np.array([p + 90.0 for p in PSI]) + g["platform_axis_azimuth_error_deg"]
        el = g["platform_axis_elevation_error_deg"]
        v0 = np.stack([np.cos(el * RAD) * np.cos(az * RAD), np.cos(el * RAD) * np.sin(az * RAD), np.sin(el * RAD)], -1)
        if tilt is None:
            tilt = "input_axis_tilt" in self.on
        if tilt:
            p = self.h["input_axis_tilt"]
            Q = np.stack([axis_tilt_matrix(p["tilt_deg"][i], p["tilt_direction_deg"][i]) for i in range(3)])
        else:
            Q = np.stack([np.eye(3)] * 3)
        return Mechanism(d1, d2, v0, Q)

    # ---- encoders ----
    def reading_from_true(self, theta_true_deg, on=None):
        """Encoder reading (deg, before quantisation) for true link angles (N,3).

        reading_i = (1+s)(theta_i - z_i)
                    + E [sin(phi_i + theta_i - kappa) - sin(phi_i + z_i - kappa)]
                    + A3 [sin(3 theta_i + rho) - sin(3 z_i + rho)]   (ripple link only)
        so that the reading is exactly 0 at theta_i = z_i (z_i = encoder_zero_offset)."""
        on = self.on if on is None else set(on)
        th = np.asarray(theta_true_deg, float)
        z = self.g["encoder_zero_offset_deg"][None, :]
        s = self.h["encoder_scale"]["relative"] if "encoder_scale" in on else 0.0
        r = (1.0 + s) * (th - z)
        if "code_wheel_eccentricity" in on:
            p = self.h["code_wheel_eccentricity"]
            E = eccentricity_peak_deg(p["e_um"])
            ph = np.array(HEAD_WHEEL_ANGLE_DEG)[None, :] - p["direction_deg"]
            r = r + E * (np.sin((ph + th) * RAD) - np.sin((ph + z) * RAD))
        for key in ("outside:ripple3", "outside:ripple"):
            if key in on:
                p = self.h[key]
                j = p["link"] - 1
                A, rho, k = p["amplitude_deg"], p["phase_deg"] * RAD, float(p.get("cycles", 3))
                r[:, j] = r[:, j] + A * (np.sin(k * th[:, j] * RAD + rho) - np.sin(k * z[0, j] * RAD + rho))
        if "outside:ripple_harmonic" in on:
            p = self.h["outside:ripple_harmonic"]
            j = p["link"] - 1
            for A, ph, k in ((p["amplitude_deg"], p["phase_deg"], p["cycles"]),
                             (p["harmonic_amplitude_deg"], p["harmonic_phase_deg"], 2 * p["cycles"])):
                r[:, j] = r[:, j] + A * (np.sin(k * th[:, j] * RAD + ph * RAD) - np.sin(k * z[0, j] * RAD + ph * RAD))
        return r

    def link_lag(self, readings_deg, on=None):
        """Per-link backlash: (N,3) link-angle shifts (deg) and the home shift (3,). Each link
        settles half its clearance behind the direction its reading last changed in; homing
        ends with every link moving + (all motors turn together at start-up)."""
        on = self.on if on is None else set(on)
        rd = np.asarray(readings_deg, float)
        n = len(rd)
        if "hinge_backlash" not in on or self.h["hinge_backlash"].get("model") != "link_lag":
            return np.zeros((n, 3)), np.zeros(3)
        half = 0.5 * np.asarray(self.h["hinge_backlash"]["clearance_deg"], float)
        last = np.ones(3)
        prev = np.zeros(3)
        out = np.empty((n, 3))
        for k in range(n):
            d = rd[k] - prev
            last = np.where(d > 0, 1.0, np.where(d < 0, -1.0, last))
            prev = rd[k]
            out[k] = -last * half
        return out, -half

    @staticmethod
    def approach_directions(readings_deg):
        """(N,3) sign of the last change of each link's reading (kept while it does not change;
        +1 before any change: homing ends with every motor turning +)."""
        rd = np.asarray(readings_deg, float)
        last = np.ones(3)
        prev = np.zeros(3)
        out = np.empty((len(rd), 3))
        for k in range(len(rd)):
            d = rd[k] - prev
            last = np.where(d > 0, 1.0, np.where(d < 0, -1.0, last))
            prev = rd[k]
            out[k] = last
        return out

    def hinge_settle(self, R, dirs, v0):
        """Leg by leg, the platform turns about its hinge axis on leg i (R v0_i, base frame) by
        -dir_i c_i / 2 (dirs (N,3), R (N,3,3))."""
        half = 0.5 * np.asarray(self.h["hinge_backlash"]["clearance_deg"], float) * RAD
        for i in range(3):
            axis = np.einsum("nab,b->na", R, v0[i])
            R = rotvec_to_R(-(dirs[:, i] * half[i])[:, None] * axis) @ R
        return R

    def true_from_reading(self, reading_deg, on=None):
        """Invert reading_from_true numerically (Newton, per element)."""
        on = self.on if on is None else set(on)
        rd = np.asarray(reading_deg, float)
        z = self.g["encoder_zero_offset_deg"][None, :]
        th = rd + z
        h = 1e-6
        for _ in range(50):
            f = self.reading_from_true(th, on) - rd
            if np.max(np.abs(f)) < 1e-12:
                break
            df = (self.reading_from_true(th + h, on) - self.reading_from_true(th - h, on)) / (2 * h)
            th = th - f / df
        return th

    # ---- platform effects ----
    def sag_rotvec(self, R_geo, on=None):
        """Gravity sag rotation vector (rad, base frame) for platform orientations (N,3,3):
        k * (c x g), c = lever arm of the platform+camera centre of mass (R_geo R_m [0,0,L])."""
        p = self.h["gravity_sag"]
        Rm = rotvec_to_R(self.g["camera_rotvec_deg"] * RAD)
        c_P = Rm @ np.array([0.0, 0.0, p["com_distance_mm"]])
        c = np.einsum("nab,b->na", R_geo, c_P)
        return np.cross(c, np.array(GRAVITY)[None, :]) * p["compliance_rad_per_mm"]

    def apply_platform_effects(self, R_geo, R_geo_home, on=None):
        """Returns (R_true (N,3,3), R_true_home (3,3))."""
        on = self.on if on is None else set(on)
        R = R_geo.copy()
        Rh = R_geo_home.copy()
        if "hinge_backlash" in on and self.h["hinge_backlash"].get("model") not in ("link_lag", "hinge_lag"):
            b = self.h["hinge_backlash"]["lag_deg"] * RAD
            n = len(R_geo)
            dirs = np.empty((n, 3))
            last = np.array(HOMING_LAST_MOTION, float)
            rv = R_to_rotvec(np.einsum("nab,ncb->nac", R_geo, np.concatenate([R_geo_home[None], R_geo[:-1]])))
            for k in range(n):
                m = np.linalg.norm(rv[k])
                if m > 1e-9:
                    last = rv[k] / m
                dirs[k] = last
            R = rotvec_to_R(-b * dirs) @ R
            Rh = rotvec_to_R(-b * np.array(HOMING_LAST_MOTION)) @ Rh
        if "gravity_sag" in on:
            R = rotvec_to_R(self.sag_rotvec(R_geo)) @ R
            Rh = rotvec_to_R(self.sag_rotvec(R_geo_home[None])[0]) @ Rh
        return R, Rh

    # ---- camera pose relative to home ----
    def camera_pose(self, R_P, R_P_home, mount=True):
        """T_rel = T_C(home)^-1 T_C(theta). Returns (R_rel (N,3,3), t_rel (N,3) mm)."""
        if mount:
            Rm = rotvec_to_R(self.g["camera_rotvec_deg"] * RAD)
            pm = np.asarray(self.g["camera_offset_mm"], float)
        else:
            Rm, pm = np.eye(3), np.zeros(3)
        RC = R_P @ Rm
        RC0 = R_P_home @ Rm
        tC = R_P @ pm
        tC0 = R_P_home @ pm
        Rrel = np.einsum("ba,nbc->nac", RC0, RC)
        trel = np.einsum("ba,nb->na", RC0, tC - tC0[None, :])
        return Rrel, trel

    def simulate(self, readings_deg, on=None, link_errors=True, nominal_mech=False, zero_offsets=True):
        """Noise-free camera poses at given encoder readings. Returns dict."""
        on = self.on if on is None else set(on)
        if nominal_mech:
            mech = Mechanism.nominal()
        else:
            mech = self.mechanism(link_errors=link_errors, tilt=("input_axis_tilt" in on))
        if zero_offsets:
            th_true = self.true_from_reading(readings_deg, on)
            th_home = self.true_from_reading(np.zeros((1, 3)), on)[0]
            lag, lag_home = self.link_lag(readings_deg, on)
            th_true, th_home = th_true + lag, th_home + lag_home
        else:
            th_true = np.asarray(readings_deg, float).copy()
            th_home = np.zeros(3)
        Rh, _, okh = mech.fk_newton(th_home.tolist(), ((1.0, 0, 0), (0, 1.0, 0), (0, 0, 1.0)))
        if not okh:
            raise RuntimeError("FK failed at home")
        R_geo, ok = mech.fk_track(th_true, R_start=Rh, theta_start=th_home)
        R_geo_h = np.array(Rh)
        Rg = np.where(ok[:, None, None], R_geo, np.eye(3))
        if "hinge_backlash" in on and self.h["hinge_backlash"].get("model") == "hinge_lag":
            dirs = self.approach_directions(readings_deg)
            Rg = self.hinge_settle(Rg, dirs, mech.v0np)
            R_geo_h = self.hinge_settle(R_geo_h[None], np.ones((1, 3)), mech.v0np)[0]
        R_P, R_Ph = self.apply_platform_effects(Rg, R_geo_h, on)
        Rrel, trel = self.camera_pose(R_P, R_Ph)
        return {"theta_true": th_true, "theta_home": th_home, "R_geo": R_geo, "R_geo_home": R_geo_h,
                "R_P": R_P, "R_rel": Rrel, "t_rel": trel, "ok": ok, "mech": mech}


def eccentricity_peak_deg(e_um):
    return (e_um * 1e-3 / READ_RADIUS_MM) * DEG


def pose_difference(a, b):
    """Rotation angle (deg) and position distance (mm) between two simulate() outputs."""
    dR = np.einsum("nba,nbc->nac", a["R_rel"], b["R_rel"])
    rot = rot_angle_deg(dR)
    pos = np.linalg.norm(a["t_rel"] - b["t_rel"], axis=-1)
    m = a["ok"] & b["ok"]
    return rot[m], pos[m]


def change_stats(a, b):
    rot, pos = pose_difference(a, b)
    return {"rms_rot_deg": float(np.sqrt(np.mean(rot**2))), "max_rot_deg": float(np.max(rot)),
            "rms_pos_mm": float(np.sqrt(np.mean(pos**2))), "max_pos_mm": float(np.max(pos))}


# --------------------------------------------------------------------------------------
# Building one set
# --------------------------------------------------------------------------------------
def command_readings():
    """Commanded grid (serpentine), nominal IK link angles, and the servoed encoder counts."""
    cmd = serpentine_grid()
    Rc = fick_to_R(cmd[:, 0], cmd[:, 1], cmd[:, 2])
    th_cmd = nominal_ik_track(Rc)
    counts = np.rint(th_cmd / DEG_PER_COUNT).astype(np.int64)
    readings = counts * DEG_PER_COUNT
    return cmd, th_cmd, counts, readings


def drifted(unit, sim):
    """The measured orientation drifts linearly with the sample's time, from 0 at the first sample
    (home is measured at the start) to end_deg about a fixed base-frame axis at the last."""
    p = unit.h["outside:drift"]
    n = len(sim["R_rel"])
    f = np.arange(n) / max(n - 1, 1)
    out = dict(sim)
    out["R_rel"] = rotvec_to_R((f * p["end_deg"] * RAD)[:, None] * np.asarray(p["axis"])[None, :]) @ sim["R_rel"]
    return out


def build_unit(seed, hidden, readings, name=None, rnd=1):
    rng = np.random.default_rng(seed)
    force = "link_angle_error" in hidden
    attempts = 0
    while True:
        attempts += 1
        geom = draw_geometry(rng, force_big_link_error=force)
        u = Unit(geom, None, [])
        # provisional hidden params needed by nothing here (no hidden effects on)
        u.h = {"encoder_scale": {"relative": 0.0}}
        full = u.simulate(readings, on=[])
        nom = u.simulate(readings, on=[], nominal_mech=True, zero_offsets=False)
        dev = change_stats(full, nom)
        if dev["max_rot_deg"] <= GEOM_MAX_ROT_DEG and dev["max_pos_mm"] <= GEOM_MAX_POS_MM and np.all(full["ok"]):
            break
        if attempts > 200:
            raise RuntimeError("could not draw a moderate unit")
    hp = {1: draw_hidden, 2: draw_hidden2, 3: draw_hidden3}[rnd](rng, *([] if rnd == 1 else [name]))
    unit = Unit(geom, hp, [h for h in hidden if h not in ("link_angle_error", "outside:drift")])
    # gravity sag: scale the compliance so that the peak sag over the workspace = target
    hp["gravity_sag"]["compliance_rad_per_mm"] = 1.0
    base = unit.simulate(readings, on=[])
    rv = unit.sag_rotvec(base["R_geo"])
    peak = float(np.max(np.linalg.norm(rv, axis=-1)))
    hp["gravity_sag"]["compliance_rad_per_mm"] = hp["gravity_sag"]["peak_deg_target"] * RAD / peak
    return unit, rng, dev, attempts


def make_set(family, idx, name, hidden, cmd, th_cmd, counts, readings):
    seed = FAMILY_SEEDS[family] * 100 + idx
    unit, rng, geodev, attempts = build_unit(seed, hidden, readings, name, round_of(family))
    sim = unit.simulate(readings)
    if "outside:drift" in hidden:
        sim = drifted(unit, sim)
    # the same unit without its hidden effect(s)
    if "link_angle_error" in hidden:
        without = unit.simulate(readings, link_errors=False)
    else:
        without = unit.simulate(readings, on=[])
    change = change_stats(sim, without) if hidden else {"rms_rot_deg": 0.0, "max_rot_deg": 0.0,
                                                        "rms_pos_mm": 0.0, "max_pos_mm": 0.0}
    per_effect = {}
    if len(hidden) > 1:
        for h in hidden:
            only = unit.simulate(readings, on=[h])
            if h == "outside:drift":
                only = drifted(unit, only)
            per_effect[h] = change_stats(only, without)
    ok = sim["ok"]
    n = len(readings)
    # measurement noise
    nrot = rng.normal(0.0, NOISE_ROT_DEG * RAD, (n, 3))
    npos = rng.normal(0.0, NOISE_POS_MM, (n, 3))
    Rm = rotvec_to_R(nrot) @ sim["R_rel"]
    fick = R_to_fick(Rm)
    pos = sim["t_rel"] + npos
    # CSV
    lines = ["seq,t_s,theta1_deg,theta2_deg,theta3_deg,alpha_deg,beta_deg,gamma_deg,x_mm,y_mm,z_mm,"
             "cmd_alpha_deg,cmd_beta_deg,cmd_gamma_deg,gx,gy,gz"]
    gs = ",".join(_fmt_g(x) for x in GRAVITY)
    seq = 0
    dropped = []
    for k in range(n):
        if not ok[k]:
            dropped.append([float(x) for x in cmd[k]])
            continue
        lines.append("%d,%.1f,%.7f,%.7f,%.7f,%.7f,%.7f,%.7f,%.5f,%.5f,%.5f,%s,%s,%s,%s" % (
            seq, SAMPLE_PERIOD_S * (seq + 1), readings[k, 0], readings[k, 1], readings[k, 2],
            fick[k, 0], fick[k, 1], fick[k, 2], pos[k, 0], pos[k, 1], pos[k, 2],
            _fmt_g(cmd[k, 0]), _fmt_g(cmd[k, 1]), _fmt_g(cmd[k, 2]), gs))
        seq += 1
    csv = "\n".join(lines) + "\n"
    # truth
    truth = {
        "file": name + ".csv",
        "seed": seed,
        "hidden": list(hidden),
        "hidden_geometric": "link_angle_error" if "link_angle_error" in hidden else None,
        "hidden_effects": {h: hidden_description(unit, h) for h in hidden},
        "hidden_effect_pose_change": change,
        "hidden_effect_pose_change_per_effect": per_effect,
        "geometry": geometry_description(unit),
        "geometric_deviation_from_nominal_mechanism": geodev,
        "geometry_draw_attempts": attempts,
        "measurement_noise": {"rot_sigma_deg_per_axis": NOISE_ROT_DEG, "pos_sigma_mm_per_axis": NOISE_POS_MM},
        "gravity_base_frame": list(GRAVITY),
        "rows": seq,
        "dropped_commands_deg": dropped,
        "true_link_angle_range_deg": [[float(np.min(sim["theta_true"][:, i])), float(np.max(sim["theta_true"][:, i]))]
                                      for i in range(3)],
    }
    return csv, truth


def _fmt_g(x):
    x = float(x)
    if x == int(x):
        return "%d" % int(x)
    return repr(x)


def _r(x, nd=9):
    if isinstance(x, np.ndarray):
        return [_r(v, nd) for v in x.tolist()]
    if isinstance(x, (list, tuple)):
        return [_r(v, nd) for v in x]
    if isinstance(x, (float, np.floating)):
        return float(f"{float(x):.{nd}g}")
    if isinstance(x, np.integer):
        return int(x)
    return x


def geometry_description(unit):
    g = unit.g
    mech = unit.mechanism(tilt=False)
    Rm = rotvec_to_R(g["camera_rotvec_deg"] * RAD)
    return {
        "conventions": "conventions.md; legs i=1,2,3 at psi=90,210,330 deg; angles deg, lengths mm",
        "encoder_zero_offset": {
            "value_deg": _r(g["encoder_zero_offset_deg"]),
            "meaning": "true link angle (deg, right-handed about +z from the nominal home) when the "
                       "encoder reads 0; true = reading + offset (absent other encoder effects)"},
        "link_angle_error": {
            "d1_error_deg": _r(g["d1_error_deg"]), "d2_error_deg": _r(g["d2_error_deg"]),
            "d1_deg": _r(D1_NOM + g["d1_error_deg"]), "d2_deg": _r(D2_NOM + g["d2_error_deg"])},
        "platform_axis_error": {
            "azimuth_error_deg": _r(g["platform_axis_azimuth_error_deg"]),
            "elevation_error_deg": _r(g["platform_axis_elevation_error_deg"]),
            "meaning": "v_i0 = [cos(el)cos(psi_i+90+daz), cos(el)sin(psi_i+90+daz), sin(el)], el = elevation error",
            "v0": _r(mech.v0np)},
        "camera_mount": {
            "rotation_vector_deg": _r(g["camera_rotvec_deg"]),
            "rotation_angle_deg": _r(float(np.linalg.norm(g["camera_rotvec_deg"]))),
            "R_platform_from_camera": _r(Rm),
            "optical_centre_offset_mm": _r(g["camera_offset_mm"]),
            "offset_norm_mm": _r(float(np.linalg.norm(g["camera_offset_mm"]))),
            "meaning": "camera frame C -> platform frame P: x_P = R x_C + offset; offset = optical centre "
                       "position in P relative to O1 (mm)"},
    }


def hidden_description(unit, h):
    p = unit.h
    if h == "input_axis_tilt":
        q = p[h]
        return {"size": _r(float(np.max(q["tilt_deg"]))), "size_unit": "deg (largest axis tilt)",
                "tilt_deg": _r(q["tilt_deg"]), "tilt_direction_deg": _r(q["tilt_direction_deg"]),
                "legs_tilted": [i + 1 for i in range(3) if q["tilt_deg"][i] > 0],
                "meaning": "link i rotates about a_i = [sin t cos d, sin t sin d, cos t] (u_i = -a_i); "
                           "the whole link (w_i) is rotated by the minimal rotation taking +z to a_i"}
    if h == "code_wheel_eccentricity":
        q = p[h]
        return {"size": _r(q["e_um"]), "size_unit": "um (wheel centre offset)",
                "peak_deg": _r(eccentricity_peak_deg(q["e_um"])),
                "direction_deg": _r(q["direction_deg"]), "read_radius_mm": READ_RADIUS_MM,
                "head_wheel_angle_at_zero_deg": list(HEAD_WHEEL_ANGLE_DEG),
                "meaning": "stationary wheel, heads turn with links; reading_i += E[sin(phi_i+theta_i-kappa) - "
                           "sin(phi_i+z_i-kappa)], E = e/r_read (deg), theta_i true link angle, "
                           "phi_i head wheel angle at theta_i=0, kappa = direction of the wheel-centre offset"}
    if h == "encoder_scale":
        q = p[h]
        return {"size": _r(q["relative"]), "size_unit": "relative (common to the three links)",
                "counts_per_true_rev": _r(COUNTS_PER_REV * (1.0 + q["relative"])),
                "meaning": "reading_i = (1+s)(theta_i - z_i): counts per true revolution = 92672 (1+s)"}
    if h == "hinge_backlash" and p[h].get("model") == "link_lag":
        q = p[h]
        return {"size": _r(float(np.max(q["clearance_deg"]))), "size_unit": "deg (largest link clearance)",
                "model": "link_lag", "clearance_deg": _r(q["clearance_deg"]),
                "meaning": "link i's true angle is shifted by -dir_i c_i / 2, dir_i the sign of the last "
                           "change of its reading (+1 at home: homing ends moving +)"}
    if h == "hinge_backlash" and p[h].get("model") == "hinge_lag":
        q = p[h]
        return {"size": _r(float(np.max(q["clearance_deg"]))), "size_unit": "deg (largest hinge clearance)",
                "model": "hinge_lag", "clearance_deg": _r(q["clearance_deg"]),
                "meaning": "leg by leg, R_P <- exp(-dir_i c_i / 2 n_i) R_P, n_i = R_P v0_i the axis of leg i's "
                           "platform hinge (base frame), dir_i the sign of the last change of link i's reading "
                           "(+1 at home)"}
    if h == "hinge_backlash":
        q = p[h]
        return {"size": _r(q["lag_deg"]), "size_unit": "deg (platform lag)",
                "model": "platform_lag",
                "meaning": "R_P = exp(-b n) R_ideal, n = unit axis of R_ideal,k R_ideal,k-1^T (base frame; "
                           "previous of the first sample = home); home was reached by a +roll (n=+z)"}
    if h == "gravity_sag":
        q = p[h]
        return {"size": _r(q["peak_deg_target"]), "size_unit": "deg (peak sag over the workspace)",
                "com_distance_mm": _r(q["com_distance_mm"]),
                "compliance_rad_per_mm": _r(q["compliance_rad_per_mm"]),
                "gravity_base_frame": list(GRAVITY),
                "meaning": "R_P = exp(k (c x g)) R_ideal, c = R_ideal R_mount [0,0,L] mm (base frame), g unit "
                           "gravity (base frame), k compliance"}
    if h == "link_angle_error":
        g = unit.g
        allerr = np.concatenate([g["d1_error_deg"], g["d2_error_deg"]])
        return {"size": _r(float(np.max(np.abs(allerr)))), "size_unit": "deg (largest arc error)",
                "d1_error_deg": _r(g["d1_error_deg"]), "d2_error_deg": _r(g["d2_error_deg"])}
    if h == "outside:ripple3":
        q = p[h]
        return {"size": _r(q["amplitude_deg"]), "size_unit": "deg (ripple amplitude)",
                "link": q["link"], "phase_deg": _r(q["phase_deg"]), "cycles_per_rev": 3,
                "meaning": "reading_j += A[sin(3 theta_j + rho) - sin(3 z_j + rho)], theta_j true link angle"}
    if h == "outside:ripple":
        q = p[h]
        return {"size": _r(q["amplitude_deg"]), "size_unit": "deg (ripple amplitude)",
                "link": q["link"], "phase_deg": _r(q["phase_deg"]), "cycles_per_rev": q["cycles"],
                "meaning": "reading_j += A[sin(k theta_j + rho) - sin(k z_j + rho)], theta_j true link angle"}
    if h == "outside:ripple_harmonic":
        q = p[h]
        return {"size": _r(q["amplitude_deg"]), "size_unit": "deg (fundamental's amplitude)",
                "link": q["link"], "cycles_per_rev": q["cycles"], "phase_deg": _r(q["phase_deg"]),
                "harmonic": {"cycles_per_rev": 2 * q["cycles"], "amplitude_deg": _r(q["harmonic_amplitude_deg"]),
                             "phase_deg": _r(q["harmonic_phase_deg"])},
                "meaning": "reading_j += A[sin(k theta_j + rho) - sin(k z_j + rho)] + A2[sin(2k theta_j + rho2) - "
                           "sin(2k z_j + rho2)], theta_j true link angle"}
    if h == "outside:drift":
        q = p[h]
        return {"size": _r(q["end_deg"]), "size_unit": "deg (drift from the first to the last sample)",
                "axis_base_frame": _r(q["axis"]),
                "meaning": "measured R_rel <- exp(f end_deg axis) R_rel, f = sample index / (rows - 1)"}
    raise KeyError(h)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "data"))
    ap.add_argument("--family", choices=sorted(FAMILY_SEEDS), action="append")
    ap.add_argument("--only", action="append", help="set name(s) to generate")
    args = ap.parse_args(argv)
    fams = args.family or ["dev", "final", "dev2", "final2", "dev3", "final3"]
    t0 = time.time()
    cmd, th_cmd, counts, readings = command_readings()
    print(f"grid: {len(cmd)} commanded poses, nominal link angles in "
          f"[{th_cmd.min():.2f}, {th_cmd.max():.2f}] deg", flush=True)
    for fam in fams:
        d = os.path.join(args.out, fam)
        os.makedirs(d, exist_ok=True)
        truth = {"family": fam, "family_seed": FAMILY_SEEDS[fam],
                 "generator": "calib/tests/independent/generate.py (written from shared/spec only)",
                 "grid": {"alpha_deg": [-30, 30, 3], "beta_deg": [-15, 15, 3], "gamma_deg": [-30, 30, 3],
                          "order": "serpentine: outer alpha ascending, middle gamma alternating, inner beta alternating"},
                 "counts_per_rev": COUNTS_PER_REV, "sample_period_s": SAMPLE_PERIOD_S,
                 "sets": {}}
        tpath = os.path.join(d, "truth.json")
        if args.only and os.path.exists(tpath):
            with open(tpath) as f:
                truth["sets"] = json.load(f).get("sets", {})
        for idx, (name, hidden) in enumerate(sets_of(fam), start=1):
            if args.only and name not in args.only:
                continue
            t1 = time.time()
            csv, tr = make_set(fam, idx, name, hidden, cmd, th_cmd, counts, readings)
            with open(os.path.join(d, name + ".csv"), "w", newline="\n") as f:
                f.write(csv)
            truth["sets"][name] = _round_tree(tr)
            c = tr["hidden_effect_pose_change"]
            print(f"[{fam}] {idx:2d}/{len(sets_of(fam))} {name:26s} rows={tr['rows']} hidden={','.join(hidden) or '-'} "
                  f"rms change {c['rms_rot_deg']:.4f} deg / {c['rms_pos_mm']:.4f} mm  ({time.time() - t1:.1f} s)",
                  flush=True)
        truth["sets"] = {n: truth["sets"][n] for n, _ in sets_of(fam) if n in truth["sets"]}
        with open(tpath, "w", newline="\n") as f:
            json.dump(truth, f, indent=1, sort_keys=False)
            f.write("\n")
    print(f"done in {time.time() - t0:.1f} s", flush=True)


def _round_tree(x):
    if isinstance(x, dict):
        return {k: _round_tree(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [_round_tree(v) for v in (x.tolist() if isinstance(x, np.ndarray) else x)]
    if isinstance(x, (float, np.floating)):
        return float(f"{float(x):.9g}")
    if isinstance(x, np.integer):
        return int(x)
    return x


if __name__ == "__main__":
    sys.exit(main())
