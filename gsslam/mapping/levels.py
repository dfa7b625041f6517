"""A coarser pyramid level for cheap early optimisation steps (issue #17).

A map step's cost is one render + backward, and most of it follows the pixels (the compositor's
pixel-Gaussian pairs, the per-pixel losses). The first ``mapper.final_coarse_share`` of the final
pass's steps therefore render at ``COARSE_FACTOR`` of the mapper resolution, against the keyframe's
image and depth reduced to that size (area average for colour, nearest pixel for depth, so unknown
depth stays unknown), like the coarse-to-fine schedules of 3DGS trainers. The keyframe's pose (and
its refinement delta) is shared, so pose gradients flow.
"""

from __future__ import annotations

import dataclasses

import torch
import torch.nn.functional as F

from gsslam.mapping.keyframes import Keyframe
from gsslam.types import CameraIntrinsics

COARSE_FACTOR = 0.5  # side of the coarse level / side of the mapper resolution


def coarse_intrinsics(intrinsics: CameraIntrinsics) -> CameraIntrinsics:
    """The camera at the coarse level (pixel-centre convention, as :meth:`CameraIntrinsics.scaled`)."""
    return intrinsics.scaled(COARSE_FACTOR)


def coarse_keyframe(kf: Keyframe, width: int, height: int) -> Keyframe:
    """A view of ``kf`` with image [h, w, 3], depth [h, w] (and depth weight) at ``width`` x ``height``.

    Everything else (pose, delta, anchor) is the keyframe's own: the same tensors, not copies.
    """
    size = (int(height), int(width))
    image = F.interpolate(kf.image.permute(2, 0, 1)[None], size=size, mode="area")[0].permute(1, 2, 0)
    depth = F.interpolate(kf.depth[None, None], size=size, mode="nearest")[0, 0]
    weight = None
    if kf.depth_weight is not None:
        weight = F.interpolate(kf.depth_weight[None, None], size=size, mode="nearest")[0, 0]
    return dataclasses.replace(kf, image=image.contiguous(), depth=depth, depth_weight=weight)


def coarse_steps(share: float, steps: int) -> int:
    """How many of ``steps`` (the first ones) run at the coarse level."""
    return int(round(min(max(share, 0.0), 1.0) * max(steps, 0)))


def camera_matrix(intrinsics: CameraIntrinsics, like: torch.Tensor) -> torch.Tensor:  # [3, 3]
    return torch.tensor(intrinsics.K, dtype=like.dtype, device=like.device)
