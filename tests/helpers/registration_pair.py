"""A registration pair (colour_focal.FlowPair) with the true depth-camera motion and the true colour flow,
from a synthetic scene misregistered as a Kinect v1 hands it out and its registered twin."""

from __future__ import annotations

import numpy as np

from gsslam.datasets.synthetic import SyntheticDataset
from gsslam.frontend.colour_focal import FlowPair
from gsslam.frontend.encoder import depth_edge_mask


def true_pair(
    misreg: SyntheticDataset, registered: SyntheticDataset, a: int, b: int, baseline_m: float
) -> FlowPair:
    """Frames a -> b with the true depth-camera motion and the true flow of colour pixels on a grid."""
    T_colour_depth = np.eye(4)
    T_colour_depth[0, 3] = baseline_m  # the depth camera's centre in the colour frame
    fa, fb = misreg[a], misreg[b]
    T_cb_ca = np.linalg.inv(fb.T_world_cam_gt) @ fa.T_world_cam_gt
    T_db_da = np.linalg.inv(T_colour_depth) @ T_cb_ca @ T_colour_depth
    c = registered.intrinsics  # the colour camera's
    z_reg = registered[a].depth  # [H, W] exact depth in the colour grid
    vs, us = np.mgrid[3 : c.height : 6, 3 : c.width : 6].reshape(2, -1)
    z = z_reg[vs, us].astype(np.float64)
    keep = np.isfinite(z) & (z > 0)
    vs, us, z = vs[keep], us[keep], z[keep]
    X = np.stack([(us - c.cx) / c.fx * z, (vs - c.cy) / c.fy * z, z], 1) @ T_cb_ca[:3, :3].T + T_cb_ca[:3, 3]
    uv_b = np.stack([c.cx + c.fx * X[:, 0] / X[:, 2], c.cy + c.fy * X[:, 1] / X[:, 2]], 1)
    depth = np.where(depth_edge_mask(fa.depth), np.nan, fa.depth).astype(np.float64)
    uv_a = np.stack([us, vs], 1).astype(np.float64)
    return FlowPair(uv_a, uv_b, depth, fa.depth, fb.depth, T_db_da)
