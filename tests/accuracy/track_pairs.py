"""Keyframe -> frame pairs of the blurred 2x teddy playback: flow PnP (by DIS preset) vs ICP on depth.

    PYTHONPATH=. python tests/accuracy/track_pairs.py [A-B ...]

For each pair (default: the 10 pairs whose PnP was refused in docs/results.md, "RGB-D tracking under
blur, session 7", and two that passed): the ground-truth motion, PnP on the tracker's grid matches
without its inlier-ratio gate (inlier share and error against the ground truth) for the DIS presets
ultrafast (the default) / fast / medium, and point-to-plane ICP of the two depth maps started from the
ultrafast PnP pose. Not a test: a measuring tool.
"""

from __future__ import annotations

import logging
import sys

import numpy as np

from gsslam.datasets.base import open_dataset
from gsslam.frontend.flow import DISFlow
from gsslam.frontend.icp import icp_point_to_plane
from gsslam.frontend.rgbd_tracking import icp_fitness, track_strides
from gsslam.frontend.tracking import grid_flow_matches, sample_depth, solve_relative_pose
from gsslam.geometry import invert_T, so3_log

PAIRS = [(11, 15), (16, 19), (18, 20), (24, 27), (162, 164), (166, 170), (203, 207), (208, 211),
         (210, 212), (216, 219), (11, 13), (40, 43)]  # fmt: skip


def _err(T: np.ndarray, G: np.ndarray) -> str:
    E = invert_T(G) @ T
    return f"{100 * np.linalg.norm(E[:3, 3]):.2f} cm {np.degrees(np.linalg.norm(so3_log(E[:3, :3]))):.2f} deg"


def main(argv: list[str]) -> int:
    logging.basicConfig(level=logging.ERROR)
    pairs = [tuple(int(x) for x in s.split("-")) for s in argv] or PAIRS
    degrade = {"shutter": 0.5, "exposure_amp": 0.25, "exposure_period": 150}
    ds = open_dataset("playback", "../shared/data/rgbd_dataset_freiburg3_teddy", base="tum",
                      pattern="fbfbf", stride=2, degrade=degrade)  # fmt: skip
    K, intr = ds.intrinsics.K, ds.intrinsics
    for a, b in pairs:
        A, B = ds[a], ds[b]
        G = invert_T(A.T_world_cam_gt) @ B.T_world_cam_gt  # T_ref_cur
        line = f"{a:3d} -> {b:3d}: motion {_err(np.eye(4), G)}"
        T_start = None
        for preset in ("ultrafast", "fast", "medium"):
            flow = DISFlow(preset, 320, 0, cache=False)(A.image, B.image)
            m = grid_flow_matches(A, B, flow, 600, depth_ref=A.depth)
            z = sample_depth(A.depth, intr, intr, m.uv_ref)
            T, inl = solve_relative_pose(m, z, K, 30, 0.0, 2.0)
            line += f" | {preset}: {inl / len(z):.2f} in, " + (_err(T, G) if T is not None else "failed")
            if preset == "ultrafast":
                T_start = T
        if T_start is not None:
            s = track_strides(intr.width)
            r = icp_point_to_plane(A.depth, B.depth, intr, invert_T(T_start), strides=s)
            fit = icp_fitness(B.depth, r.inliers, s[-1])
            line += f" | ICP from ultrafast: {r.ok} {r.reason} fitness {fit:.3f}, "
            line += _err(invert_T(r.T_tgt_src), G)
        print(line, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
