"""Intra-submap pose refinement of keyframes against the map (SING3R), anchored so it cannot drift.

The data term is photometric L1 under the rendered alpha mask plus ``lambda_pose_depth`` x the
scale-invariant depth term; the prior pulls each keyframe's se(3) delta toward its anchor (the given
pose, or the accepted pose-only refinement). See docs/mapping.md, "Pose refinement that cannot drift".
"""

from __future__ import annotations

import logging

import torch

from gsslam.config import MapperConfig
from gsslam.mapping import exposure as X
from gsslam.mapping import losses as L
from gsslam.mapping.adam import Adam
from gsslam.mapping.keyframes import Keyframe
from gsslam.mapping.rasterize import RenderOutput
from gsslam.mapping.state import MapState, render

_log = logging.getLogger(__name__)


def pose_prior(cfg: MapperConfig, kf: Keyframe, weight: float | None = None) -> torch.Tensor:
    """Anchors the delta: ``weight * (|rho / (r z_med)|^2 + |phi / r|^2)``.

    ``r`` is ``pose_prior_rel``; ``z_med`` the keyframe's median depth; ``weight`` defaults to
    ``lambda_pose_prior``.
    """
    r = cfg.pose_prior_rel
    w = cfg.lambda_pose_prior if weight is None else weight
    return w * (
        ((kf.delta[:3] - kf.anchor[:3]) / (r * kf.median_depth)).square().sum()
        + ((kf.delta[3:] - kf.anchor[3:]) / r).square().sum()
    )


def pose_loss(
    cfg: MapperConfig, out: RenderOutput, kf: Keyframe, prior: bool = True, prior_weight: float | None = None
) -> torch.Tensor:
    """Photometric L1 (through the keyframe's exposure) + scale-invariant depth under ``alpha > 0.9``
    (+ :func:`pose_prior`)."""
    mask = out.alpha.detach() > 0.9
    expo = None if kf.exposure is None else kf.exposure.detach()  # fitted by its own loss, not here
    color = X.apply(out.color, expo, out.alpha)  # [H, W, 3] the render through the keyframe's exposure
    loss = L.l1(color, kf.image, mask) + cfg.lambda_pose_depth * L.scale_invariant_depth(
        out.depth, kf.depth, mask
    )
    return loss + pose_prior(cfg, kf, prior_weight) if prior else loss


def refine_pose(state: MapState, kf: Keyframe, iterations: int) -> float:
    """Pose-only refinement of ``kf`` against the frozen map; returns the last loss.

    The best delta is kept only when it lowers the data loss by ``pose_min_gain`` (relative);
    otherwise the given pose stands (an imperfect map must not pull a good pose away).
    """
    cfg = state.cfg
    start = kf.delta.detach().clone()
    kf.delta = start.clone().requires_grad_(True)
    opt = Adam([{"params": [kf.delta], "lr": cfg.lr_pose_init}])
    m = state.model.detached()
    first = best = value = float("nan")
    best_delta = start
    for _ in range(max(0, iterations)):
        out = render(state, kf.T_cam_world(state.device), m)
        data = pose_loss(cfg, out, kf, prior=False)
        value = float(data.detach())
        if first != first:  # nan: the first evaluation is at the given pose
            first = best = value
        elif value < best:
            best, best_delta = value, kf.delta.detach().clone()
        loss = data + cfg.pose_init_prior * pose_prior(cfg, kf)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
    accept = best < (1.0 - cfg.pose_min_gain) * first
    kf.delta = best_delta if accept else start
    kf.anchor = kf.delta.clone()
    _log.debug(
        "pose refinement of %d: %.4f -> %.4f (%s)", kf.index, first, best, "kept" if accept else "rejected"
    )
    return best if accept else first
