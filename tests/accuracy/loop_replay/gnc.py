"""Measuring tool (docs/results.md, "Loops that correct, session 9"), not a test: a kept run's graph solved in
two stages: first with Gaussian flow factors (inlier prior ~1; then also without the ICP Huber kernel),
then the run's own factors by LM from there; keyframe ATE Sim(3) and the run graph's error.
Usage: ``PYTHONPATH=. python tests/accuracy/loop_replay/gnc.py KEPT.pkl``."""
import pickle, sys, numpy as np, gtsam
from pathlib import Path
sys.path.insert(0, str(Path(__file__).parent))
from replay import replay, ate, kf_poses
st = pickle.load(open(sys.argv[1], 'rb'))
def flow_gauss(sp):
    if sp[0] != "flow": return sp
    kw = dict(sp[2]); kw["inlier_prior"] = 0.999999; return (sp[0], sp[1], kw)
def nohuber(sp):
    if sp[0] == "flow": return flow_gauss(sp)
    if sp[0] == "relative_pose":
        k, a, kw = sp; return (k, (a[0], a[1], a[2], a[3], 0.0, *a[5:]), kw)
    return sp
_, _, be = replay(st, batch=True)
g = gtsam.NonlinearFactorGraph()
for h in sorted(be._factors): g.add(be._factors[h])
print("as run: error %.6g kf ATE %.3f" % (g.error(be.values()), ate(st, kf_poses(be.values(), st))))
for name, m in (("flow gaussian", flow_gauss), ("flow gaussian + ICP no huber", nohuber)):
    a, b, be1 = replay(st, other_map=m, batch=True)
    v1 = be1.values()
    p = gtsam.LevenbergMarquardtParams(); p.setMaxIterations(100)
    r = gtsam.LevenbergMarquardtOptimizer(g, v1, p).optimize()
    print("%s: stage 1 kf ATE %.3f; then the run's graph from there: error %.6g kf ATE %.3f" % (name, b, g.error(r), ate(st, kf_poses(r, st))))
