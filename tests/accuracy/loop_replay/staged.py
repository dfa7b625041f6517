"""Measuring tool (docs/results.md, "The graph's basin, session 10"), not a test: a kept run's graph
(``exp.py``) replayed up to the final batch, then the batch solved each way (``graph.batch_solve`` =
lm / staged, :mod:`gsslam.graph.staged_solve`); keyframe ATE Sim(3) (cm) and the run graph's error.
With two pickles (ON OFF) also the loops-off graph at the loops-on solution minus its loops.
Usage: ``PYTHONPATH=. python tests/accuracy/loop_replay/staged.py KEPT.pkl [OFF.pkl]``."""
import pickle, sys
from pathlib import Path
import gtsam
sys.path.insert(0, str(Path(__file__).parent))
from replay import replay, ate, kf_poses


def graph_of(be):
    g = gtsam.NonlinearFactorGraph()
    for h in sorted(be._factors):
        g.add(be._factors[h])
    return g


for path in sys.argv[1:]:
    st = pickle.load(open(path, "rb"))
    print(path, "kept kf ATE before/after batch (as run): see exp.py; loops", st["loops"].get("in_graph"))
    for method in ("lm", "staged"):
        before, after, be = replay(st, overrides=[f"graph.batch_solve={method}"], batch=True)
        r = be.last_batch
        print(f"  {method:7s} kf ATE before batch {before:.3f} after {after:.3f}; error {r.error_initial:.6g} -> "
              f"{r.error_final:.6g}" + (f" (relaxed stage {r.error_relaxed:.6g}, {r.relaxed_factors} factors)"
                                        if r.error_relaxed is not None else ""))
if len(sys.argv) == 3:
    on = pickle.load(open(sys.argv[1], "rb")); off = pickle.load(open(sys.argv[2], "rb"))
    _, _, be_off = replay(off, batch=True)
    _, _, be_on = replay(on, loop_map=lambda sp: None, batch=True)
    g = graph_of(be_off)
    print("off graph error at its own solution %.6g (kf %.3f), at the on-minus-loops solution %.6g (kf %.3f)" % (
        g.error(be_off.values()), ate(off, kf_poses(be_off.values(), off)),
        g.error(be_on.values()), ate(on, kf_poses(be_on.values(), on))))
