"""Replay a run kept by ``exp.py`` with its RGB-D point loops re-weighted (docs/results.md, "Loops that
correct, session 9"): keyframe ATE (Sim(3), cm) before / after the final batch.

Variants: ``asis``; ``off`` (no loop weight); ``gtloop`` (each loop's points moved to the relative pose
of its two submaps at their best rigid fit to ground truth, ``loop_audit.gt_local_best``); ``agg=S``
(per-point sigma = S metres x sqrt(N): S is the std of the loop's aggregate misalignment, as the
adjacency factors do); ``minn=N`` (loops of fewer than N point pairs dropped); ``icpw=F`` (the
neighbour ICP factors' information x F); ``icpfloor=T,R`` (their covariance + T^2 m^2 / (R deg)^2); ``sig=S`` (per-point sigma S metres, as ``graph.loop_sigma_m``).
Usage: ``PYTHONPATH=. python tests/accuracy/loop_replay/agg_rexp.py KEPT.pkl asis off agg=0.005 ...``.
"""
import pickle
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from loop_audit import gt_local_best  # noqa: E402
from replay import replay  # noqa: E402

from gsslam.geometry import invert_T  # noqa: E402
from gsslam.graph.keys import submap_key  # noqa: E402


def gt_all_pairs(st, min_overlap, index):
    """The run's loops as they are, plus a point loop at the best-rigid ground-truth relative pose for every
    submap pair (m < i - 2) of ground-truth overlap > ``min_overlap`` that has none (500 points on a grid at
    submap m's median depth, per-point sigma graph.loop_sigma_m); keyframe ATE after the final batch."""
    from loop_audit import FOV, frustum_overlap
    from replay import ate, kf_poses

    from gsslam.graph.factor_specs import build_factor

    _, _, be = replay(st, batch=False)
    have = {(lc["i"], lc["m"]) for lc in st["loopc"]}
    ns, added = len(st["frame_indices"]), 0
    u, v = np.meshgrid(np.linspace(-FOV[0], FOV[0], 25), np.linspace(-FOV[1], FOV[1], 20))
    for i in range(ns):
        for m in range(i - 2):
            if (i, m) in have or frustum_overlap(st, i, m) <= min_overlap:
                continue
            z = st["enc_depth_med"][m]
            X_m = np.stack([u.ravel() * z, v.ravel() * z, np.full(u.size, z)], 1)
            G = invert_T(gt_local_best(st, i)) @ gt_local_best(st, m)
            sp = ("point", (submap_key(i), submap_key(m), X_m @ G[:3, :3].T + G[:3, 3], X_m, 0.05), {})
            be.add_factor(build_factor(sp), f"gt loop {i}-{m}", spec=sp)
            added += 1
    be.update()
    a = ate(st, kf_poses(be.values(), st))
    be.refine_batch()
    b = ate(st, kf_poses(be.values(), st))
    return f"{added} ground-truth loops added: kf ATE Sim(3) before batch {a:.3f} after batch {b:.3f} cm"


def main():
    st = pickle.load(open(sys.argv[1], "rb"))
    index = {submap_key(k): k for k in range(len(st["frame_indices"]))}

    def with_sigma(fn):
        def m(sp):
            k, a, kw = sp
            return (k, (*a[:4], float(fn(len(a[2])))), kw)
        return m

    def gt_loop(sp):
        k, a, kw = sp
        i, m = index[int(a[0])], index[int(a[1])]
        G = invert_T(gt_local_best(st, i)) @ gt_local_best(st, m)
        return (k, (a[0], a[1], a[3] @ G[:3, :3].T + G[:3, 3], a[3], *a[4:]), kw)

    for name in sys.argv[2:]:
        if name == "asis":
            kw = {}
        elif name == "off":
            kw = dict(loop_map=lambda sp: None)
        elif name == "gtloop":
            kw = dict(loop_map=gt_loop)
        elif name.startswith("agg="):
            s = float(name[4:])
            kw = dict(loop_map=with_sigma(lambda n, s=s: s * np.sqrt(n)))
        elif name.startswith("icpw="):  # the ICP relative-pose factors (loop.icp_neighbours): information x F
            f = float(name[5:])

            def icp_scaled(sp, f=f):
                if sp[0] != "relative_pose":
                    return sp
                k, a, kw = sp
                return (k, (a[0], a[1], a[2], a[3] * f, *a[4:]), kw)
            kw = dict(other_map=icp_scaled)
        elif name.startswith("icpfloor="):  # neighbour ICP covariance + diag(r^2 (rad), t^2 (m)): "icpfloor=T_M,R_DEG"
            t_m, r_deg = (float(x) for x in name[9:].split(","))

            def icp_floor(sp, t_m=t_m, r=np.radians(r_deg)):
                if sp[0] != "relative_pose":
                    return sp
                k, a, kw = sp
                cov = np.linalg.inv(a[3]) + np.diag([r * r] * 3 + [t_m * t_m] * 3)
                return (k, (a[0], a[1], a[2], np.linalg.inv(cov), *a[4:]), kw)
            kw = dict(other_map=icp_floor)
        elif name.startswith("minn="):  # loops with fewer than this many point pairs get no weight
            t = int(name[5:])
            kw = dict(loop_map=lambda sp, t=t: None if len(sp[1][2]) < t else sp)
        elif name.startswith("sig="):
            s = float(name[4:])
            kw = dict(loop_map=with_sigma(lambda n, s=s: s))
        elif name.startswith("gtall="):  # recall bound: a ground-truth loop for every overlapping pair
            print(name + ": " + gt_all_pairs(st, float(name[6:]), index), flush=True)
            continue
        else:
            raise SystemExit(f"unknown variant {name}")
        a, b, _ = replay(st, **kw)
        print(f"{name}: kf ATE Sim(3) before batch {a:.3f} after batch {b:.3f} cm", flush=True)


if __name__ == "__main__":
    main()
