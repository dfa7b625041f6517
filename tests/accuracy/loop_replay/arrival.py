"""Measuring tool (docs/results.md, "The graph's basin, session 10"), not a test: a kept run's graph
(``paired.py`` / ``exp.py``) replayed with the iSAM2 handling changed where a loop arrives (the first update
after a loop factor was added): ``asis``; ``extraN`` (N more Gauss-Newton iterations there); ``batch`` /
``staged`` (a batch re-solve there, one-shot or staged); ``relin=T`` (relinearisation threshold T everywhere).
Prints the keyframe ATE Sim(3) (cm) before and after the final batch.
Usage: ``PYTHONPATH=. python tests/accuracy/loop_replay/arrival.py KEPT.pkl asis extra5 batch staged relin=0.001``."""
import pickle, sys, time
from pathlib import Path
import gtsam
sys.path.insert(0, str(Path(__file__).parent))
from replay import ate, is_loop, kf_poses  # noqa: E402
from gsslam.config import load_config
from gsslam.factors import to_gtsam
from gsslam.graph.backend import Backend
from gsslam.graph.factor_specs import build_factor


def run(st, variant):
    over = ["mapper.enabled=false"]
    if variant.startswith("relin="):
        over.append(f"graph.relinearize_threshold={variant[6:]}")
    if variant == "staged":
        over.append("graph.batch_solve=staged")
    be = Backend.from_config(load_config(None, over, mode="rgbd").graph)
    loop_pending, n_arrivals = False, 0
    for op in st["replay"]:
        if op[0] == "factor":
            be.add_factor(build_factor(op[2]), op[1], spec=op[2])
            # a loop: point loops, or an ICP relative pose further back than loop.icp_neighbours (3)
            loop_pending |= is_loop(op[2]) or op[2][0] == "relative_pose" and int(op[2][1][0]) > int(op[2][1][1]) + 3
        elif op[0] == "value":
            be.add_value(int(op[1]), to_gtsam(op[2], "sim3"))
        elif op[0] == "remove":
            be.remove_factors([int(h) for h in op[1]])
        elif op[0] == "update":
            extra = int(op[1])
            if loop_pending and variant.startswith("extra"):
                extra += int(variant[5:])
            try:
                be.update(extra)
            except Exception as e:  # noqa: BLE001 - as the run passed over rejected updates
                print("update failed", e)
            if loop_pending and variant in ("batch", "staged"):
                be.refine_batch()
            n_arrivals += loop_pending
            loop_pending = False
    a = ate(st, kf_poses(be.values(), st))
    be.refine_batch()
    return a, ate(st, kf_poses(be.values(), st)), n_arrivals


st = pickle.load(open(sys.argv[1], "rb"))
for v in sys.argv[2:]:
    t = time.time()
    a, b, n = run(st, v)
    print(f"{v}: kf ATE Sim(3) before final batch {a:.3f} after {b:.3f}; {n} loop arrivals; {time.time() - t:.0f} s", flush=True)
