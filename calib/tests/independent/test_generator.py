#!/usr/bin/env python3
"""Self-test of the independent generator (plain asserts; run: python3 test_generator.py).

1. kinematic identities of the nominal eye (roll, FK(IK(R)) = R, home = 0, working mode);
2. the unit model: encoder inversion, loop closure of the unit, sequential vs batch FK;
3. every CSV under data/ is exactly what generate.py produces now (byte for byte), its
   readings are whole counts, and its measured poses scatter about the noise-free poses
   by the stated measurement noise;
4. each hidden effect changes the (noise-free) poses by about its stated size relative to
   the same unit without it; prints the table for both families.

Options: --data DIR (default: data next to this file), --quick (the development families only),
--family F (only F; repeatable).
"""
import argparse
import io
import json
import math
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import generate as G  # noqa: E402

# a hidden effect's RMS pose change must at least reach the per-axis noise sigma
NOISE_FLOOR = G.NOISE_ROT_DEG
I3 = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


def check_kinematics(cmd, th_cmd):
    nom = G.Mechanism.nominal()
    # equal link motion = pure roll by t about the optical axis (beta = +t)
    for t in (-40.0, -15.0, -3.0, 0.0, 2.5, 15.0, 40.0):
        R, _, ok = nom.fk_newton([t, t, t], I3)
        assert ok
        f = G.R_to_fick(np.array(R))
        assert abs(f[0]) < 1e-10 and abs(f[2]) < 1e-10 and abs(f[1] - t) < 1e-10, (t, f)
        assert np.max(np.abs(np.array(R) - G.Rz(np.array(t * G.RAD)))) < 1e-12
    # nominal pose at theta = 0 is zero
    R0, _, ok = nom.fk_newton([0.0, 0.0, 0.0], I3)
    assert ok and np.max(np.abs(np.array(R0) - np.eye(3))) < 1e-15
    unit = G.Unit(G.draw_geometry(np.random.default_rng(1)), G.draw_hidden(np.random.default_rng(2)), [])
    unit.h["gravity_sag"]["compliance_rad_per_mm"] = 1e-4
    for on in ([], ["hinge_backlash"], ["gravity_sag", "input_axis_tilt", "code_wheel_eccentricity"]):
        s = unit.simulate(np.zeros((1, 3)), on=on)
        p = np.concatenate([G.R_to_fick(s["R_rel"])[0], s["t_rel"][0]])
        assert np.max(np.abs(p)) < 1e-12, (on, p)
    # FK(IK(R)) = R over the workspace, serpentine grid and a random dense sample
    Rc = G.fick_to_R(cmd[:, 0], cmd[:, 1], cmd[:, 2])
    R, ok = nom.fk_track(th_cmd)
    assert ok.all()
    e1 = np.max(np.abs(R - Rc))
    rng = np.random.default_rng(5)
    rnd = np.column_stack([rng.uniform(-30, 30, 3000), rng.uniform(-15, 15, 3000), rng.uniform(-30, 30, 3000)])
    Rr = G.fick_to_R(rnd[:, 0], rnd[:, 1], rnd[:, 2])
    th_r = G.nominal_ik_roots(Rr)[..., 0]
    Rb = nom.fk_batch(th_r, Rr @ G.rotvec_to_R(rng.normal(0, 0.03, (3000, 3))))
    e2 = np.max(np.abs(Rb - Rr))
    assert e1 < 1e-9 and e2 < 1e-9, (e1, e2)
    # Fick round trip
    f = G.R_to_fick(Rr)
    assert np.max(np.abs(f - rnd)) < 1e-9
    # working mode: the tracked root is the closed-form "minus" root everywhere, the
    # links move continuously along the serpentine, and the other root is far away
    roots = G.nominal_ik_roots(Rc)
    assert np.max(np.abs(G.wrap_deg(roots[..., 0] - th_cmd))) < 1e-9
    assert np.min(np.abs(G.wrap_deg(roots[..., 1] - th_cmd))) > 60.0
    assert np.max(np.abs(np.diff(th_cmd, axis=0))) < 6.0
    # Loop-closure Jacobian well away from singular over the workspace
    v = np.einsum("nab,ib->nia", Rc, nom.v0np)
    J = np.cross(v, nom.w_batch(th_cmd))
    dets = np.abs(np.linalg.det(J))
    print(f"kinematics: FK(IK) max err {max(e1, e2):.1e}, roll check ok, home = 0, "
          f"|det J| in [{dets.min():.3f}, {dets.max():.3f}], link angles in [{th_cmd.min():.2f}, {th_cmd.max():.2f}] deg")
    return dets.min()


def check_unit_model(unit, readings, sim):
    # encoder inversion: the effect-laden reading of the true angle is the count exactly
    # (the true angles carry the per-link backlash lag, which is not a reading effect)
    lag, _ = unit.link_lag(readings)
    back = unit.reading_from_true(sim["theta_true"] - lag)
    assert np.max(np.abs(back - readings)) < 1e-9
    # loop closure of the unit's mechanism at the true angles
    mech = sim["mech"]
    res = mech.residual_batch(sim["theta_true"], sim["R_geo"])
    assert np.max(np.abs(res)) < 1e-12, np.max(np.abs(res))
    # sequential warm-started FK agrees with a batch Newton started from the command
    cmd = G.serpentine_grid()
    Rc = G.fick_to_R(cmd[:, 0], cmd[:, 1], cmd[:, 2])
    Rb = mech.fk_batch(sim["theta_true"], Rc)
    assert np.max(np.abs(Rb - sim["R_geo"])) < 1e-10


def read_csv(path):
    with open(path) as f:
        head = f.readline().strip().split(",")
        data = np.loadtxt(f, delimiter=",")
    return {h: data[:, i] for i, h in enumerate(head)}


def equiv_deg(name, hd, sim):
    """Size of a hidden effect as an angle (deg) for the comparison with the pose change."""
    if name == "code_wheel_eccentricity":
        return hd["peak_deg"]
    if name == "outside:drift":
        return hd["size"]
    if name == "encoder_scale":
        travel = np.max(np.abs(sim["theta_true"] - sim["theta_home"][None, :]))
        return abs(hd["size"]) * travel
    return hd["size"]


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=os.path.join(HERE, "data"))
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--family", action="append", help="only these families")
    args = ap.parse_args(argv)

    cmd, th_cmd, counts, readings = G.command_readings()
    assert len(cmd) == 21 * 11 * 21 == 4851
    steps = np.abs(np.diff(cmd, axis=0))
    assert np.all(np.sort(steps, axis=1)[:, :2] == 0) and np.all(steps.max(axis=1) == 3.0)
    assert len({tuple(r) for r in cmd}) == 4851
    check_kinematics(cmd, th_cmd)

    table = []
    fams = ["dev", "dev2", "dev3"] if args.quick else ["dev", "final", "dev2", "final2", "dev3", "final3"]
    fams = args.family or fams
    seeds = {}
    for fam in fams:
        truth = json.load(open(os.path.join(args.data, fam, "truth.json")))
        assert truth["family_seed"] == G.FAMILY_SEEDS[fam]
        assert [n for n, _ in G.sets_of(fam)] == list(truth["sets"])
        for idx, (name, hidden) in enumerate(G.sets_of(fam), start=1):
            tr = truth["sets"][name]
            seeds[(fam, name)] = tr["seed"]
            assert tr["hidden"] == hidden
            # byte-for-byte reproduction of the file
            csv, tr_now = G.make_set(fam, idx, name, hidden, cmd, th_cmd, counts, readings)
            path = os.path.join(args.data, fam, name + ".csv")
            with open(path) as f:
                assert f.read() == csv, f"{path} differs from what generate.py makes now"
            assert json.loads(json.dumps(G._round_tree(tr_now))) == tr, f"truth of {fam}/{name} is stale"
            d = read_csv(path)
            n = len(d["seq"])
            assert n == tr["rows"] == 4851 and not tr["dropped_commands_deg"]
            assert np.all(np.diff(d["seq"]) > 0) and np.all(np.diff(d["t_s"]) > 0)
            th = np.column_stack([d["theta1_deg"], d["theta2_deg"], d["theta3_deg"]])
            c = th / G.DEG_PER_COUNT
            assert np.max(np.abs(c - np.rint(c))) < 1e-3
            assert np.array_equal(np.rint(c).astype(np.int64), counts)
            # re-simulate the unit noise-free and compare with the measured poses
            rnd = G.round_of(fam)
            unit, _, _, _ = G.build_unit(tr["seed"], hidden, readings, name, rnd)
            sim = unit.simulate(readings)
            # a few units with different effects (the checks are slow-ish)
            if idx in {1: (1, 2, 9, 11), 2: (2, 6), 3: (1, 2)}[rnd]:
                check_unit_model(unit, readings, sim)
            if "outside:drift" in hidden:
                sim = G.drifted(unit, sim)
            Rm = G.fick_to_R(d["alpha_deg"], d["beta_deg"], d["gamma_deg"])
            nrot = G.R_to_rotvec(np.einsum("nab,ncb->nac", Rm, sim["R_rel"])) * G.DEG
            npos = np.column_stack([d["x_mm"], d["y_mm"], d["z_mm"]]) - sim["t_rel"]
            sr, sp = nrot.std(axis=0), npos.std(axis=0)
            assert np.all(np.abs(sr / G.NOISE_ROT_DEG - 1) < 0.06), sr
            assert np.all(np.abs(sp / G.NOISE_POS_MM - 1) < 0.06), sp
            assert np.all(np.abs(nrot.mean(axis=0)) < 0.001) and np.all(np.abs(npos.mean(axis=0)) < 0.005)
            geodev = tr["geometric_deviation_from_nominal_mechanism"]
            assert geodev["max_rot_deg"] <= G.GEOM_MAX_ROT_DEG and geodev["max_pos_mm"] <= G.GEOM_MAX_POS_MM
            # hidden effect size vs pose change
            ch = tr["hidden_effect_pose_change"]
            ratios = []
            for h in hidden:
                hd = tr["hidden_effects"][h]
                per = tr["hidden_effect_pose_change_per_effect"].get(h, ch)
                r = per["max_rot_deg"] / equiv_deg(h, hd, sim)
                ratios.append(f"{r:.2f}")
                assert 0.25 <= r <= 4.0, (fam, name, h, r)
                # and the effect stands above the noise floor in RMS
                assert per["rms_rot_deg"] > 1.0 * NOISE_FLOOR, (fam, name, h, per)
            if not hidden:
                assert ch["max_rot_deg"] == 0.0
            sizes = "; ".join(f"{h}={tr['hidden_effects'][h]['size']:.4g} {tr['hidden_effects'][h]['size_unit'].split(' ')[0]}"
                              + (f" ({tr['hidden_effects'][h]['peak_deg']:.3f} deg)" if "peak_deg" in tr['hidden_effects'][h] else "")
                              for h in hidden) or "-"
            table.append((fam, name, ",".join(hidden) or "-", sizes, ch["rms_rot_deg"], ch["max_rot_deg"],
                          ch["rms_pos_mm"], ch["max_pos_mm"], ",".join(ratios) or "-"))
            print(f"  ok {fam}/{name}  noise rot {np.round(sr, 4)} deg, pos {np.round(sp, 4)} mm", flush=True)

    out = io.StringIO()
    out.write("| family | set | hidden | size | RMS rot change deg | max rot deg | RMS pos change mm | max pos mm | max/size |\n")
    out.write("| --- | --- | --- | --- | --- | --- | --- | --- | --- |\n")
    for r in table:
        out.write(f"| {r[0]} | {r[1]} | {r[2]} | {r[3]} | {r[4]:.4f} | {r[5]:.4f} | {r[6]:.4f} | {r[7]:.4f} | {r[8]} |\n")
    print()
    print(out.getvalue())
    print("seeds:", ", ".join(f"{f}/{n}={s}" for (f, n), s in seeds.items()))
    print("all checks passed")


if __name__ == "__main__":
    main()
