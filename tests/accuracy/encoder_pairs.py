"""RGB-D encoder keyframe pairs: PnP on checked flow at 320 px vs ICP vs both jointly, against ground truth.

    PYTHONPATH=. python tests/accuracy/encoder_pairs.py STRIDE GAP [WEIGHT]  # 2 2: 2x, blur; 1 4: as recorded

About 30 pairs ``GAP`` played frames apart over teddy played forward at ``STRIDE`` (with blur and exposure
swings when STRIDE > 1), posed as the RGB-D encoder poses consecutive keyframes (``pnp_from_flow``,
1 px), by point-to-plane ICP from that pose and by both jointly (``joint_pose``, flow weight
``WEIGHT``, default 1; ``encoder.rgbd_joint_pose``); prints each pair and the median / mean errors.
Not a test: a measuring tool (docs/results.md, "RGB-D tracking under blur, session 7" and "RGB-D
keyframe poses from flow and depth, session 8").
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
    stride, gap = int(argv[0]), int(argv[1])
    weight = float(argv[2]) if len(argv) > 2 else 1.0
    blur = {"shutter": 0.5, "exposure_amp": 0.25, "exposure_period": 150} if stride > 1 else None
    ds = open_dataset("playback", "../shared/data/rgbd_dataset_freiburg3_teddy", base="tum", pattern="f",
                      stride=stride, degrade=blur)  # fmt: skip
    flow = make_flow_estimator(load_config(None, [], mode="rgbd").flow)
    intr = pointmap_intrinsics(ds.intrinsics, 320)
    rng = np.random.default_rng(0)
    nan2 = (float("nan"), float("nan"))
    rows = []
    for k in range(0, len(ds) - gap, max(1, len(ds) // 30)):
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
        start = res.T_tgt_src if res.T_tgt_src is not None else np.eye(4)
        icp = icp_point_to_plane(dA, dB, intr, start, strides=ICP_STRIDES)
        joint = joint_pose(X, uv_t, dA, dB, intr, start, flow_weight=weight, strides=ICP_STRIDES)
        ep = _err(res.T_tgt_src, G) if res.T_tgt_src is not None else nan2
        ei = _err(icp.T_tgt_src, G) if icp.ok else nan2
        ej = _err(joint.T_tgt_src, G) if joint.ok and res.T_tgt_src is not None else nan2
        mot = _err(np.eye(4), G)
        rows.append((*mot, *ep, *ei, *ej))
        print(f"{k:3d} motion {mot[0]:.1f} cm {mot[1]:.1f} deg | PnP {res.inliers:4d} inliers of "
              f"{int(valid.sum()):5d}: {ep[0]:.2f} cm {ep[1]:.2f} deg | ICP {ei[0]:.2f} cm {ei[1]:.2f} deg"
              f" | joint {ej[0]:.2f} cm {ej[1]:.2f} deg", flush=True)  # fmt: skip
    R = np.array(rows, float)[:, 2:]
    for name, f in (("median", np.nanmedian), ("mean", np.nanmean)):
        p = f(R, 0)
        print(f"{name}: PnP {p[0]:.2f} cm {p[1]:.2f} deg | ICP {p[2]:.2f} cm {p[3]:.2f} deg | "
              f"joint {p[4]:.2f} cm {p[5]:.2f} deg ({len(R)} pairs)")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
