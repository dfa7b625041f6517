"""Seeding: new Gaussians only where a keyframe sees unmapped space (SING3R's global map growth).

A pixel is unmapped when the rendered alpha is below ``unmapped_alpha`` or the measured surface lies
well in front of the rendered one (``< 0.7 x``). Every ``init_stride``-th such pixel becomes an
isotropic Gaussian at the back-projected (hole-inpainted) depth, coloured by the image, sized by the
pixel footprint.
"""

from __future__ import annotations

import logging

import torch

from gsslam.mapping.gaussians import GaussianModel
from gsslam.mapping.keyframes import Keyframe, fill_depth
from gsslam.mapping.state import MapState, render

_log = logging.getLogger(__name__)


@torch.no_grad()
def seed_gaussians(state: MapState, kf: Keyframe) -> int:
    """Add Gaussians for the unmapped pixels of ``kf`` to ``state.model``; returns how many."""
    cfg = state.cfg
    h, w = kf.depth.shape
    stride = max(1, cfg.init_stride)
    unmapped = torch.ones(h, w, dtype=torch.bool, device=state.device)
    if len(state.model):
        out = render(state, kf.T_cam_world(state.device))
        in_front = torch.isfinite(kf.depth) & (kf.depth < 0.7 * out.depth)
        unmapped = (out.alpha < cfg.unmapped_alpha) | in_front
    sel = torch.zeros_like(unmapped)
    oy, ox = (int(v) for v in state.rng.integers(0, stride, size=2))
    sel[oy::stride, ox::stride] = True
    sel &= unmapped
    vv, uu = torch.nonzero(sel, as_tuple=True)
    if len(vv) == 0:
        return 0
    z = fill_depth(kf.depth)[vv, uu]
    ok = torch.isfinite(z) & (z > 0)
    vv, uu, z = vv[ok], uu[ok], z[ok]
    K = state.intrinsics
    x = (uu.float() - K.cx) / K.fx * z
    y = (vv.float() - K.cy) / K.fy * z
    p_cam = torch.stack([x, y, z], dim=-1)
    T_wc = torch.linalg.inv(kf.T_cam_world(state.device))
    p_world = p_cam @ T_wc[:3, :3].T + T_wc[:3, 3]
    scales = z / K.fx * stride * 0.6
    new = GaussianModel.from_points(
        p_world, kf.image[vv, uu], scales, kf.submap_id, kf.index, opacity=cfg.init_opacity
    )
    room = cfg.max_gaussians - len(state.model)
    if room <= 0:
        _log.warning("Gaussian cap %d reached; keyframe %d adds nothing", cfg.max_gaussians, kf.index)
        return 0
    if len(new) > room:
        new = new.select(torch.randperm(len(new), generator=state.gen)[:room].to(state.device))
    state.model = state.model.cat(new)
    state.densify_state = state.strategy.grow_state(state.densify_state, len(new))
    return len(new)
