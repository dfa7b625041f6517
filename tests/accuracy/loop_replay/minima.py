"""Measuring tool (docs/results.md, "Loops that correct, session 9"), not a test: the loops-off graph of a
row evaluated at its own solution and at the loops-on run's solution (loop factors removed; the other
factors are identical), then LM continued from its own. Usage: ``PYTHONPATH=. python minima.py ON.pkl OFF.pkl``."""
import pickle, sys, numpy as np, gtsam
from pathlib import Path
sys.path.insert(0, str(Path(__file__).parent))
from replay import replay, ate, kf_poses
on = pickle.load(open(sys.argv[1], 'rb')); off = pickle.load(open(sys.argv[2], 'rb'))
_, _, be_off = replay(off, batch=True)
_, _, be_on = replay(on, loop_map=lambda sp: None, batch=True)
def graph_of(be):
    g = gtsam.NonlinearFactorGraph()
    for h in sorted(be._factors): g.add(be._factors[h])
    return g
g_off = graph_of(be_off)
v_off, v_on = be_off.values(), be_on.values()
print("off graph error at the loops-off solution %.6g, at the loops-on-minus-loops solution %.6g" % (g_off.error(v_off), g_off.error(v_on)))
print("kf ATE Sim3 off solution %.3f, on-minus-loops solution %.3f" % (ate(off, kf_poses(v_off, off)), ate(on, kf_poses(v_on, on))))
params = gtsam.LevenbergMarquardtParams(); params.setMaxIterations(1000); params.setRelativeErrorTol(1e-10); params.setAbsoluteErrorTol(1e-10)
opt = gtsam.LevenbergMarquardtOptimizer(g_off, v_off, params); r = opt.optimize()
print("off, LM 1000 its from its own solution: iterations %d error %.6g kf ATE %.3f" % (opt.iterations(), g_off.error(r), ate(off, kf_poses(r, off))))
