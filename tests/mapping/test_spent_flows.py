"""Stored keyframe flows are forgotten once no step can read them, without changing the map."""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from gsslam.config import MapperConfig
from gsslam.mapping.mapper import GaussianMapper
from gsslam.mapping.window import flows_read_at_end

CFG = MapperConfig(max_side=80, iterations=6, window=2, device="cpu", pose_refinement=False)


def _map(frames, cfg):
    """Keyframes in turn, each with a flow from its predecessor, a window optimisation after each."""
    torch.manual_seed(0)
    m = GaussianMapper(cfg, frames[0].intrinsics)
    flow = np.full((480, 640, 2), 3.0, np.float32)
    valid = np.ones((480, 640), bool)
    kept = []
    for k, f in enumerate(frames):
        m.add_keyframe(f, f.T_world_cam_gt, submap_id=0)
        if k:
            m.add_flow(frames[k - 1].index, f.index, flow, valid)
        m.optimize()
        kept.append(sorted(m.map.flows))
    return m, kept


def test_flows_whose_target_left_the_window_are_dropped_and_the_map_is_the_same(teddy_frames):
    i = [f.index for f in teddy_frames]
    m, kept = _map(teddy_frames, CFG)
    # window 2: a flow (a, b) is read while b is one of the two newest keyframes
    assert kept == [[], [(i[0], i[1])], [(i[0], i[1]), (i[1], i[2])], [(i[1], i[2]), (i[2], i[3])]]
    assert not flows_read_at_end(CFG)
    # a pass over all keyframes that weighs flows keeps every one; the window steps never read
    # final_lambda_flow, so the maps must be bit for bit the same
    keep_all = dataclasses.replace(CFG, final_lambda_flow=1e-9)
    assert flows_read_at_end(keep_all)
    m_all, kept_all = _map(teddy_frames, keep_all)
    assert len(kept_all[-1]) == 3
    for k, v in m.model.params().items():
        assert torch.equal(v, m_all.model.params()[k]), k
    assert flows_read_at_end(dataclasses.replace(CFG, final_pose_iterations=5))
    assert not flows_read_at_end(dataclasses.replace(CFG, final_pose_iterations=5, lambda_flow=0.0))
