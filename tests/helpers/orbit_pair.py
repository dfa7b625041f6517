"""A synthetic orbit pair with DIS flow and exact ground truth, for the mono two-view tests."""

from __future__ import annotations

import numpy as np

from gsslam.config import load_config
from gsslam.datasets.synthetic.dataset import SyntheticDataset
from gsslam.frontend.flow import forward_backward_mask, make_flow_estimator, textured_mask
from gsslam.geometry import invert_T


def orbit_dataset() -> SyntheticDataset:
    """60 frames orbiting the textured room (seed 5)."""
    return SyntheticDataset(n_frames=60, trajectory="orbit", seed=5)


def orbit_flow_pair(orbit: SyntheticDataset, i: int = 0, j: int = 8):
    """``(K, flow i -> j, forward-backward + texture mask, T_j_i)`` of frames ``i`` and ``j``."""
    flow = make_flow_estimator(load_config(None, [], mode="mono").flow)
    a, b = orbit[i], orbit[j]
    fw, bw = flow(a.image, b.image), flow(b.image, a.image)
    ok = forward_backward_mask(fw, bw, 1.0, relative=0.01) & textured_mask(a.image, 0.01)
    T_b_a = invert_T(b.T_world_cam_gt) @ a.T_world_cam_gt
    return a.intrinsics.K, fw, ok, np.asarray(T_b_a)
