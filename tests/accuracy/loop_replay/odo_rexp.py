"""Replay an RGB-D run kept by ``exp.py --keep-depth`` with ICP factors between each new submap and its
recent predecessors added (docs/results.md, "RGB-D loops, session 7"): the loop factors as run, removed
(``off``) or replaced by ICP relative poses (``icp``), and "odometry" ICP relative poses from submap k to
submaps k-1 (a pair of distinct keyframes) ... k-B. Keyframe ATE (Sim(3)) online and after the batch, and after the batch under SE(3).
Usage: ``PYTHONPATH=. python odo_rexp.py PKL [loops:back:n_eff[:n_loop] ...]``, e.g. ``off:0:100``
(loops off, no odometry ICP), ``asis:3:100``, ``icp:2:30:100``."""
import dataclasses, pickle, sys
import numpy as np
sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))  # replay.py
import replay as rp
from gsslam.config import LoopConfig, load_config
from gsslam.factors import to_gtsam, to_matrix
from gsslam.graph.backend import Backend
from gsslam.graph.factor_specs import build_factor
from gsslam.graph.keys import submap_key
from gsslam.loop.icp_loop import icp_relative_pose
from gsslam.eval.ate import compute_ate
from gsslam.types import Trajectory

st = pickle.load(open(sys.argv[1], "rb"))
encs, key_of = rp.kept_encodings(st)
lcs = {(d["i"], d["m"]): d["T_i_m"] for d in st["loopc"]}
CFG1 = dataclasses.replace(LoopConfig(), icp_effective_points=1.0)
_cache = {}


def icp(i, m, T_guess):
    key = (i, m, T_guess is None)
    if key not in _cache:
        _cache[key] = icp_relative_pose(lcs[(i, m)] if T_guess is None else T_guess, encs[i], encs[m], CFG1)
    return _cache[key]


def run(name):
    parts = name.split(":")
    loops, back, n_eff = parts[0], int(parts[1]), float(parts[2])
    n_loop = float(parts[3]) if len(parts) > 3 else 100.0
    be = Backend.from_config(load_config(None, ["mapper.enabled=false"], mode="rgbd").graph)
    new_sub, n_odo = [], 0
    for op in st["replay"]:
        if op[0] == "factor":
            sp = op[2]
            if rp.is_loop(sp):
                i, m = key_of[int(sp[1][0])], key_of[int(sp[1][1])]
                if loops == "off":
                    k, a, kw = sp; sp = (k, (*a[:4], 1e6), kw)
                elif loops == "icp":
                    r = icp(i, m, None)
                    if r is not None:
                        sp = ("relative_pose", (sp[1][0], sp[1][1], r.T_i_m, r.information * n_loop, 3.0, "sim3"), {})
            be.add_factor(build_factor(sp), None, spec=sp)
        elif op[0] == "value":
            be.add_value(int(op[1]), to_gtsam(op[2], "sim3"))
            if int(op[1]) in key_of:
                new_sub.append(key_of[int(op[1])])
        elif op[0] == "update":
            for k in new_sub:  # odometry ICP: submap k against k-1 .. k-back, guess from the estimate
                Sk = to_matrix(be.estimate(submap_key(k)))
                for j in range(max(0, k - back), k):
                    Sj = to_matrix(be.estimate(submap_key(j)))
                    G = np.linalg.inv(Sk) @ Sj
                    U, _, Vt = np.linalg.svd(G[:3, :3]); G[:3, :3] = U @ Vt  # rigid (RGB-D scale ~1)
                    r = icp(k, j, G)
                    if r is None:
                        continue
                    sp = ("relative_pose", (submap_key(k), submap_key(j), r.T_i_m, r.information * n_eff, 3.0, "sim3"), {})
                    be.add_factor(build_factor(sp), None, spec=sp); n_odo += 1
            new_sub = []
            be.update(int(op[1]))
    a = rp.ate(st, rp.kf_poses(be.values(), st))
    be.refine_batch()
    P = rp.kf_poses(be.values(), st)
    return a, rp.ate(st, P), n_odo, ate_se3(P)


def ate_se3(P):  # keyframe ATE (cm) under a rigid alignment, as the runner reports RGB-D
    ks = sorted(P)
    tr = Trajectory(np.array([st["ts"][k] for k in ks]), np.stack([P[k] for k in ks]))
    return 100 * compute_ate(st["gt"], tr, align="se3")[0].stats.rmse


if __name__ == "__main__":
    for name in sys.argv[2:]:
        a, b, n, c = run(name)
        print(f"{name:20s} kf ATE (Sim(3)) online {a:.3f} cm, after batch {b:.3f} cm, SE(3) {c:.3f} cm "
              f"({n} odometry ICP factors)", flush=True)
