"""Mono + IMU (synthesized) on a TUM sequence with a gap: every chain's graph against the mocap.

    PYTHONPATH=.:tests python tests/accuracy/imu_chains.py /tmp/rgbd_dataset_freiburg3_gap100

(build the gap copy as in docs/results.md "Gaps: chains re-joined", with A=100, B=130). Prints, per
chain, the scale error and SE(3) ATE of the chain's *graph* keyframe poses (docs/results.md, "IMU in
the run, session 5").
"""

import logging
import sys

import numpy as np

from gsslam.config import load_config
from gsslam.datasets.tum import TumRgbdDataset
from gsslam.geometry import umeyama
from gsslam.slam.imu_stage import ImuStage
from gsslam.slam.pipeline import Pipeline

logging.basicConfig(level=logging.WARNING)
cfg = load_config(None, ["imu.enabled=true", "mapper.enabled=false"], mode="mono")
ds = TumRgbdDataset(sys.argv[1], imu="synthesized", with_depth=False)
st = ImuStage(cfg, ds.imu(), ds.T_body_cam)
pipe = Pipeline(cfg, ds.intrinsics)
pipe.add_plugin(st)
for i in range(len(ds)):
    pipe.process(ds[i])
pipe.close_chain()
pipe.finish()
gt = ds.ground_truth()


def gt_pos(t):
    return np.array([np.interp(t, gt.timestamps, gt.poses[:, k, 3]) for k in range(3)])


ts = ds.timestamps()
print(
    "chains", len(pipe.chains), "imu chains", sorted(st.chains), "report later", st.report.get("later_chains")
)
for cid, ch in enumerate(pipe.chains):
    P = ch.graph.keyframe_poses()
    fr = [f for f in sorted(P) if gt.timestamps[0] <= ts[f] <= gt.timestamps[-1]]
    X = np.array([P[f][:3, 3] for f in fr])
    Y = np.array([gt_pos(ts[f]) for f in fr])
    T = umeyama(X, Y, with_scale=True)
    s = np.cbrt(np.linalg.det(T[:3, :3]))
    R = umeyama(X, Y, with_scale=False)
    ate = np.sqrt(((X @ R[:3, :3].T + R[:3, 3] - Y) ** 2).sum(1).mean())
    n_imu = len(st.chains[cid].states) if cid in st.chains else 0
    print(
        f"chain {cid}: {len(fr)} keyframes, in_world {ch.in_world}, "
        f"graph scale error {abs(s - 1) * 100:.2f} %, "
        f"graph SE(3) ATE {ate * 100:.2f} cm, IMU states {n_imu}"
    )
