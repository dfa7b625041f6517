"""Joint flow + depth keyframe pose (frontend/joint_pose.py) by flow weight, on many teddy keyframe pairs.

    PYTHONPATH=. python tests/accuracy/joint_pose_sweep.py STRIDE GAP NPAIRS WEIGHTS  # e.g. 2 2 100 0,0.3,1,3

As ``encoder_pairs.py`` (pairs ``GAP`` played frames apart, teddy played forward at ``STRIDE``, blur when
STRIDE > 1, PnP on forward-backward-checked flow at 320 px) but about ``NPAIRS`` pairs, the flows computed
once and the joint pose solved for every flow weight in ``WEIGHTS`` (0: ICP alone). Prints median / mean
errors against ground truth. Not a test: docs/results.md, "RGB-D keyframe poses from flow and depth,
session 8".
"""

from __future__ import annotations

import logging
import sys

import numpy as np

from gsslam.config import load_config
from gsslam.datasets.base import open_dataset
from gsslam.frontend.encoder import pointmap_intrinsics, resize_depth, resize_image
from gsslam.frontend.flow import forward_backward_mask, make_flow_estimator, resize_flow, textured_mask
from gsslam.frontend.icp import icp_point_to_plane
from gsslam.frontend.joint_pose import joint_pose
from gsslam.frontend.pose_estimation import pnp, random_flow_matches
from gsslam.frontend.rgbd_encoder import ICP_STRIDES
from gsslam.geometry import backproject, invert_T, so3_log


def _err(T: np.ndarray, G: np.ndarray) -> tuple[float, float]:  # -> (cm, deg)
    E = invert_T(G) @ T
    return 100 * float(np.linalg.norm(E[:3, 3])), float(np.degrees(np.linalg.norm(so3_log(E[:3, :3]))))


def main(argv: list[str]) -> int:
    logging.basicConfig(level=logging.ERROR)
    stride, gap, npairs = int(argv[0]), int(argv[1]), int(argv[2])
    weights = [float(w) for w in argv[3].split(",")]
    blur = {"shutter": 0.5, "exposure_amp": 0.25, "exposure_period": 150} if stride > 1 else None
    ds = open_dataset("playback", "../shared/data/rgbd_dataset_freiburg3_teddy", base="tum", pattern="f",
                      stride=stride, degrade=blur)  # fmt: skip
    flow = make_flow_estimator(load_config(None, [], mode="rgbd").flow)
    intr = pointmap_intrinsics(ds.intrinsics, 320)
    rng = np.random.default_rng(0)
    errs: dict[str, list] = {"PnP": [], "ICP": [], **{f"joint w={w:g}": [] for w in weights}}
    for k in range(0, len(ds) - gap, max(1, len(ds) // npairs)):
        A, B = ds[k], ds[k + gap]
        if A.T_world_cam_gt is None or B.T_world_cam_gt is None:
            continue
        G = invert_T(B.T_world_cam_gt) @ A.T_world_cam_gt  # T_tgt_src (B <- A)
        dA, dB = resize_depth(A.depth, intr), resize_depth(B.depth, intr)
        for d in (dA, dB):
            d[~(d > 0.1)] = np.nan
        fw = resize_flow(flow(A.image, B.image), intr.width, intr.height)
        bw = resize_flow(flow(B.image, A.image), intr.width, intr.height)
        valid = forward_backward_mask(fw, bw, 1.0) & textured_mask(resize_image(A.image, intr))
        uv_s, uv_t, z = random_flow_matches(fw, valid, dA, 3000, rng)
        X = backproject(intr.K, uv_s, z)
        res = pnp(X, uv_t, intr.K, 1.0, 30)
        if res.T_tgt_src is None:
            continue
        nan2 = (float("nan"), float("nan"))
        errs["PnP"].append(_err(res.T_tgt_src, G))
        icp = icp_point_to_plane(dA, dB, intr, res.T_tgt_src, strides=ICP_STRIDES)
        errs["ICP"].append(_err(icp.T_tgt_src, G) if icp.ok else nan2)
        for w in weights:
            j = joint_pose(X, uv_t, dA, dB, intr, res.T_tgt_src, flow_weight=w, strides=ICP_STRIDES)
            errs[f"joint w={w:g}"].append(_err(j.T_tgt_src, G) if j.ok else nan2)
    for name, e in errs.items():
        e = np.array(e, float)
        med, mean = np.nanmedian(e, 0), np.nanmean(e, 0)
        print(f"{name:>14}: median {med[0]:.3f} cm {med[1]:.3f} deg | mean {mean[0]:.3f} cm {mean[1]:.3f} deg"
              f" | {np.isfinite(e[:, 0]).sum()} pairs")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
