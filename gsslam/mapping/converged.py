"""The converged part of the map: what feedback to the graph may be measured against (issue #13).

A Gaussian counts as *converged* when the keyframe that seeded it is at least ``mapper.feedback_min_age``
keyframes older than the newest: it has left the optimisation window (``mapper.window``) and had its
revisit steps since. The young Gaussians, seeded by the keyframes just before, carry the same drift as a
new frame (the map agreeing with the odometry: circular evidence, docs/results.md "Feedback"); the old
ones are the map of a region seen long ago, so evidence against them on a revisit is loop-like.

- :func:`converged_mask`: the converged Gaussians [N] bool;
- :func:`converged_share`: how much of a view the map covers and which share of the rendered weight
  there the converged Gaussians explain (rendered as a colour channel: no kernel change);
- :func:`converged_view`: a :class:`MapState` whose model holds only them (the map is unchanged);
- :func:`converged_owners`: which submaps' converged Gaussians explain a view, by share of the rendered
  weight (the owners a relative registration is measured against, ``mapper.registration_relative``);
- :func:`converged_depth`: rendered depths of the converged Gaussians alone at a pose (depth priors);
- :func:`covered_depths`: well-covered pixels of any render and their depths.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from gsslam.geometry import split_sim3
from gsslam.mapping.rasterize import render as rasterize
from gsslam.mapping.state import MapState, render


def converged_mask(state: MapState, min_age: int) -> torch.Tensor:  # -> [N] bool
    """Gaussians seeded by a keyframe at least ``min_age`` keyframes before the newest (0: all)."""
    model = state.model
    if min_age <= 0:
        return torch.ones(len(model), dtype=torch.bool, device=model.means.device)
    old = state.order[: max(0, len(state.order) - min_age)]
    return torch.isin(model.keyframe_id, torch.tensor(old, dtype=torch.int64, device=model.means.device))


@torch.no_grad()
def converged_share(state: MapState, T_cam_world: torch.Tensor, mask: torch.Tensor) -> tuple[float, float]:
    """(coverage, share) of the view ``T_cam_world`` [4, 4]: the fraction of pixels the whole map covers
    (alpha > 0.9), and the share of the rendered weight there from the Gaussians in ``mask`` [N]."""
    m = state.model
    if len(m) == 0 or not bool(mask.any()):  # nothing converged yet: no render needed
        return 0.0, 0.0
    flag = mask.float()[:, None].expand(-1, 3).contiguous()  # [N, 3]
    out = rasterize(
        m.means, m.quats, m.scales, m.opacities, flag, T_cam_world, state.K,
        state.intrinsics.width, state.intrinsics.height, backend=state.backend,
    )  # fmt: skip
    covered = out.alpha > 0.9
    if not bool(covered.any()):
        return 0.0, 0.0
    share = (out.color[..., 0][covered] / out.alpha[covered]).clamp(0, 1).mean()
    return float(covered.float().mean()), float(share)


def converged_view(state: MapState, mask: torch.Tensor) -> MapState:
    """A view of ``state`` whose model holds only the Gaussians in ``mask`` [N] (detached copies)."""
    if bool(mask.all()):
        return state
    return dataclasses.replace(state, model=state.model.select(mask))


@torch.no_grad()
def converged_owners(state: MapState, T_world_cam: np.ndarray) -> dict[int, float]:
    """Share of the converged view's rendered weight (pixels with alpha > 0.9) per submap id, at the pose
    ``T_world_cam`` [4, 4]: the submaps whose Gaussians a registration there was measured against.

    Candidates are the submaps with a converged Gaussian centre in the view; their shares come from renders
    of the converged Gaussians with one flag channel per candidate (three per render), so occlusion and
    opacity count as in the registration's own render. Empty when nothing converged covers the view."""
    mask = converged_mask(state, state.cfg.feedback_min_age)
    m = state.model
    if len(m) == 0 or not bool(mask.any()):
        return {}
    T = cam_world(state, T_world_cam)
    view = m.select(mask)
    Xc = view.means.detach() @ T[:3, :3].T + T[:3, 3]  # [M, 3]
    z = Xc[:, 2]
    uv = Xc[:, :2] / z.clamp(min=1e-6)[:, None] * torch.diagonal(state.K)[:2] + state.K[:2, 2]  # [M, 2]
    W, H = state.intrinsics.width, state.intrinsics.height
    inside = (z > 1e-3) & (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
    ids = torch.unique(view.submap_id[inside]).tolist()
    shares: dict[int, float] = {}
    for g in range(0, len(ids), 3):
        group = ids[g : g + 3]
        flags = torch.zeros(len(view), 3, device=view.means.device)  # [M, 3]
        for c, i in enumerate(group):
            flags[:, c] = (view.submap_id == i).float()
        out = rasterize(view.means, view.quats, view.scales, view.opacities, flags, T, state.K, W, H,
                        backend=state.backend)  # fmt: skip
        covered = out.alpha > 0.9
        total = float(out.alpha[covered].sum())
        if total <= 0:
            return {}
        for c, i in enumerate(group):
            shares[int(i)] = float(out.color[..., c][covered].sum()) / total
    return shares


def cam_world(state: MapState, T_world_cam: np.ndarray) -> torch.Tensor:  # [4, 4] Sim(3) -> rigid T_cam_world
    R, t, _ = split_sim3(np.asarray(T_world_cam, dtype=np.float64))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R.T, -R.T @ t
    return torch.as_tensor(T, dtype=torch.float32, device=state.device)


@torch.no_grad()
def converged_depth(
    state: MapState,
    T_world_cam: np.ndarray,  # [4, 4] SE(3) or Sim(3): the frame's pose (the rigid part is the camera)
    n_points: int,
    min_alpha: float = 0.99,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Depths of the converged Gaussians alone at up to ``n_points`` pixels they cover (alpha >
    ``min_alpha``): (uv [N, 2] at the mapper resolution, depth [N] world units, converged share).
    Nothing where their share of the view is below ``feedback_min_converged`` (a view of young map)."""
    T_cam_world = cam_world(state, T_world_cam)
    mask = converged_mask(state, state.cfg.feedback_min_age)
    _, share = converged_share(state, T_cam_world, mask)
    if share < state.cfg.feedback_min_converged or not bool(mask.any()):
        return np.zeros((0, 2)), np.zeros(0), share
    uv, depth = covered_depths(
        render(converged_view(state, mask), T_cam_world), n_points, state.rng, min_alpha
    )
    return uv, depth, share


def covered_depths(
    out, n_points: int, rng: np.random.Generator, min_alpha: float
) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``n_points`` random pixels of a render with alpha > ``min_alpha`` and a positive depth:
    (uv [N, 2] at the render's resolution, depth [N] world units)."""
    ok = (out.alpha > min_alpha) & (out.depth > 0)
    vv, uu = (a.cpu().numpy() for a in torch.nonzero(ok, as_tuple=True))
    if len(vv) > n_points:
        pick = rng.choice(len(vv), size=n_points, replace=False)
        vv, uu = vv[pick], uu[pick]
    depth = out.depth.cpu().numpy()[vv, uu].astype(np.float64)
    return np.stack([uu, vv], axis=1).astype(np.float64), depth
