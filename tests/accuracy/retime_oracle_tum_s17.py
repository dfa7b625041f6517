"""Session 17 (merged), an instrument: teddy-200 (TUM, registered) re-timed by a given delay with the mocap's
true motion over it (the ground truth interpolated) instead of the tracked velocity. docs/results.md,
"Session 17 merged".

    PYTHONPATH=. python3 tests/accuracy/retime_oracle_tum_s17.py DELAY_S OUT [DATA_ROOT]
"""

import json
import logging
import sys
from pathlib import Path

import numpy as np

import gsslam.run.sequence as sequence
from gsslam.config import load_config
from gsslam.datasets import open_dataset
from gsslam.frontend.depth_retiming import DepthRetimer
from gsslam.geometry import interpolate_pose
from gsslam.io.trajectory import read_tum

tau, out = float(sys.argv[1]), Path(sys.argv[2])
data = Path(sys.argv[3]) if len(sys.argv) > 3 else Path("../shared/data")
root = data / "rgbd_dataset_freiburg3_teddy"
gt = read_tum(root / "groundtruth.txt")
ts, P = np.asarray(gt.timestamps), np.asarray(gt.poses)


def pose_at(t):
    i = int(np.clip(np.searchsorted(ts, t) - 1, 0, len(ts) - 2))
    return interpolate_pose(P[i], P[i + 1], (t - ts[i]) / (ts[i + 1] - ts[i]))


class Oracle(DepthRetimer):
    def _motion(self, timestamp):
        return np.linalg.inv(pose_at(timestamp)) @ pose_at(timestamp + self.delay_s)


logging.basicConfig(level=logging.WARNING)
sequence.DepthRetimer = Oracle
cfg = load_config(None, ["mapper.enabled=false", f"encoder.depth_delay_s={tau}"], mode="rgbd")
ds = open_dataset("tum", root)
res = sequence.run_dataset(ds, cfg, out, overwrite=True)

m = json.load(open(out / "metrics.json"))
print(tau, m["ate"]["rmse_m"])
