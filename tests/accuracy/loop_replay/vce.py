"""Measuring tool (docs/results.md, "The graph's basin, session 10"), not a test: factor weights from their
measured error (variance components). A kept run's graph (``paired.py``) is replayed up to the final
batch and solved by LM; then, per factor class (flow, adjacency points, submap alignment, scale,
neighbour ICP poses, loop ICP poses), the mean whitened squared residual per dimension at the solution
(``2 error / dim``) rescales that class's information (divided by it), and LM solves again from the
first solution; repeated ``ROUNDS`` times. Prints per class the ratio and the keyframe ATE Sim(3) (cm).
Usage: ``PYTHONPATH=. python tests/accuracy/loop_replay/vce.py KEPT.pkl [ROUNDS]``."""
import pickle, sys
from collections import defaultdict
from pathlib import Path
import numpy as np, gtsam
sys.path.insert(0, str(Path(__file__).parent))
from replay import replay, ate, kf_poses  # noqa: E402
from gsslam.factors import to_matrix  # noqa: E402,F401
from gsslam.graph.factor_specs import build_factor  # noqa: E402
from gsslam.graph.staged_solve import one_shot_solve  # noqa: E402


def cls(s):
    if s is None:
        return None
    kind, a, kw = s
    if kind == "relative_pose":
        return "icp_loop" if int(a[0]) - int(a[1]) > 3 else "icp_neighbour"
    if kind == "point":
        return "adjacency" if int(a[0]) < int(a[1]) else "point_loop"
    return kind if kind in ("flow", "submap_alignment", "scale") else None


def scaled(s, r):  # the spec with its information divided by r
    kind, a, kw = s
    if kind == "flow":
        w = kw.get("weight")
        return kind, a, {**kw, "weight": (np.ones(len(a[2])) if w is None else np.asarray(w)) / r}
    if kind == "relative_pose":
        return kind, (*a[:3], np.asarray(a[3]) / r, *a[4:]), kw
    if kind == "point":
        return kind, (*a[:4], a[4] * np.sqrt(r), *a[5:]), kw
    if kind == "submap_alignment":
        return kind, (*a[:3], a[3] * np.sqrt(r), a[4] * np.sqrt(r), *a[5:]), kw
    if kind == "scale":
        return kind, (*a[:3], a[3] * np.sqrt(r), *a[4:]), kw
    raise ValueError(kind)


st = pickle.load(open(sys.argv[1], "rb"))
rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 2
a0, _, be = replay(st, batch=False)
hs = sorted(be._factors)
specs = [be._specs.get(h) for h in hs]
factors = [be._factors[h] for h in hs]
v, _ = one_shot_solve(factors, gtsam.Values(be.values()), 100)
print("before batch %.4f; LM %.4f" % (a0, ate(st, kf_poses(v, st))))
total = defaultdict(lambda: 1.0)
for k in range(rounds):
    chi, dim = defaultdict(float), defaultdict(int)
    for f, s in zip(factors, specs):
        c = cls(s)
        if c:
            chi[c] += 2 * f.error(v); dim[c] += f.dim()
    ratio = {c: chi[c] / dim[c] for c in chi}
    for c in ratio:
        total[c] *= ratio[c]
    factors = [be._factors[h] if cls(s) is None else build_factor(scaled(s, total[cls(s)])) for h, s in zip(hs, specs)]
    v, _ = one_shot_solve(factors, v, 100)
    print("round %d: ratios %s -> kf ATE %.4f" % (k + 1, {c: round(r, 3) for c, r in ratio.items()}, ate(st, kf_poses(v, st))), flush=True)
