"""MapStage feedback paths with a stub map: what the next submap and the graph receive."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import torch

from gsslam.config import MapperConfig
from gsslam.slam.map_stage import MapStage


def _stage(depth: torch.Tensor, alpha: torch.Tensor, scale: float) -> tuple[MapStage, list]:
    stage = MapStage.__new__(MapStage)  # no real mapper: render_keyframe is all shared_depth reads
    stage.cfg = MapperConfig()
    stage.mapper = SimpleNamespace(render_keyframe=lambda index: SimpleNamespace(depth=depth, alpha=alpha))
    stage._anchor = {7: (0, 0, 0)}
    S = np.diag([scale, scale, scale, 1.0])
    chains = [SimpleNamespace(T_world_chain=np.eye(4), graph=SimpleNamespace(submap_pose=lambda s: S))]
    return stage, chains


def test_shared_depth_replaces_only_measured_opaque_pixels():
    """Inpainted pixels (no point-map depth) and half-transparent ones keep the encoder's depth."""
    h, w = 6, 8
    depth = torch.full((h, w), 4.0)  # world units
    alpha = torch.ones(h, w)
    alpha[:, w // 2 :] = 0.5
    stage, chains = _stage(depth, alpha, scale=2.0)
    pointmap = np.full((h, w), 1.5, np.float32)
    pointmap[:2] = np.nan  # the texture mask left these without depth
    out = stage.shared_depth(chains, 7, pointmap)
    assert np.all(np.isnan(out[:2]))  # never filled from the map's inpainted Gaussians
    np.testing.assert_allclose(out[2:, : w // 2], 2.0)  # rendered, in submap units (4 m / scale 2)
    np.testing.assert_allclose(out[2:, w // 2 :], 1.5)  # alpha 0.5: the encoder's own depth
    assert stage.shared_depth(chains, 99, pointmap) is pointmap  # not a mapper keyframe
