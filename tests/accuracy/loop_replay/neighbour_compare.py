"""Measuring tool (docs/results.md, "Loops that correct, session 9"), not a test: the neighbour ICP factors
(``loop.icp_neighbours``) of two kept runs of one row (e.g. loops on / off), each measured ``T_i_m`` against
the two submaps at their best rigid poses (``gsslam.eval.submaps``). Usage:
``PYTHONPATH=. python tests/accuracy/loop_replay/neighbour_compare.py ON.pkl OFF.pkl``.
"""
import pickle
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from loop_audit import gt_local_best  # noqa: E402

from gsslam.eval.submaps import loop_reference, pose_difference  # noqa: E402
from gsslam.graph.keys import submap_key  # noqa: E402


def neighbour_errors(st):
    index = {submap_key(k): k for k in range(len(st["frame_indices"]))}
    best = {k: gt_local_best(st, k) for k in range(len(st["frame_indices"]))}
    out = {}
    for op in st["replay"]:
        if op[0] == "factor" and op[2][0] == "relative_pose":
            a = op[2][1]
            i, m = index[int(a[0])], index[int(a[1])]
            if i - m <= 3:  # neighbours (loops refined by ICP would be farther apart)
                out[(i, m)] = pose_difference(a[2], loop_reference(best[i], best[m]))
    return out


def main():
    runs = [neighbour_errors(pickle.load(open(p, "rb"))) for p in sys.argv[1:]]
    common = sorted(set.intersection(*[set(r) for r in runs]))
    print(f"{len(common)} neighbour pairs in all runs (of {[len(r) for r in runs]})")
    for p, r in zip(sys.argv[1:], runs):
        t = np.array([r[k][0] for k in common]) * 1e3
        d = np.array([r[k][1] for k in common])
        print(f"{Path(p).name}: error vs best poses median {np.median(t):.2f} mm / {np.median(d):.3f} deg, "
              f"p90 {np.percentile(t, 90):.2f} mm / {np.percentile(d, 90):.3f} deg")  # fmt: skip


if __name__ == "__main__":
    main()
