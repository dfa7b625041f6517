"""The mapper's state, explicit: everything the map stages read and write, in one object.

Like gsplat's strategy + state dict, the stages are plain functions of a :class:`MapState`:
:func:`gsslam.mapping.seeding.seed_gaussians`, :func:`gsslam.mapping.pose_refine.refine_pose`,
:func:`gsslam.mapping.window.optimize_window`, :func:`gsslam.mapping.final_pass.finalize` /
:func:`~gsslam.mapping.final_pass.refine_joint` and :mod:`gsslam.mapping.outputs`. They replace
``state.model`` and ``state.densify_state`` as they optimise, grow and prune the map;
:class:`gsslam.mapping.mapper.GaussianMapper` is the facade that owns one state and calls them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from gsslam.config import MapperConfig
from gsslam.geometry import split_sim3
from gsslam.mapping.densify import DensifyStrategy
from gsslam.mapping.gaussians import GaussianModel
from gsslam.mapping.keyframes import Keyframe, MapperError
from gsslam.mapping.projection import LOW_PASS
from gsslam.mapping.rasterize import RenderOutput
from gsslam.mapping.rasterize import render as rasterize
from gsslam.types import CameraIntrinsics


@dataclass
class MapState:
    """The Gaussian map, its densification state, the keyframes and flows it is optimised on."""

    cfg: MapperConfig
    device: torch.device
    intrinsics: CameraIntrinsics  # at the mapper resolution
    K: torch.Tensor  # [3, 3] of ``intrinsics``
    strategy: DensifyStrategy
    model: GaussianModel
    densify_state: dict[str, torch.Tensor]  # per-Gaussian error statistics (``strategy``'s state)
    keyframes: dict[int, Keyframe] = field(default_factory=dict)
    order: list[int] = field(default_factory=list)  # keyframe indices in insertion order
    flows: dict[tuple[int, int], tuple[torch.Tensor, torch.Tensor]] = field(default_factory=dict)
    # (a, b) -> (flow [h, w, 2] a -> b at the mapper resolution, valid [h, w] bool)
    steps: dict[int, int] = field(default_factory=dict)  # keyframe index -> map steps rendered at it so far
    rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(0))
    gen: torch.Generator = field(default_factory=lambda: torch.Generator().manual_seed(0))
    backend: str = "auto"  # the rasterizer every render uses: "c" | "torch" | "gsplat" (resolved once)

    def keyframe(self, index: int) -> Keyframe:
        if index not in self.keyframes:
            raise MapperError(f"frame {index} is not a mapper keyframe (known: {self.order[-5:]}...)")
        return self.keyframes[index]


def render(
    state: MapState,
    T_cam_world: torch.Tensor,  # [4, 4]
    model: GaussianModel | None = None,
    intrinsics: CameraIntrinsics | None = None,
) -> RenderOutput:
    """Render ``model`` (default: the state's) from ``T_cam_world`` at the mapper resolution.

    ``intrinsics`` renders another camera instead (e.g. the input's full resolution for evaluation);
    one ``z`` times finer than the mapper's gets the screen-space dilation scaled with it
    (:func:`zoom_low_pass`). Only the Gaussians in view are projected and composited (``cull``: the
    same images and gradients, at a cost that follows the view, not the map).
    """
    m = state.model if model is None else model
    if intrinsics is not None:
        K = torch.tensor(intrinsics.K, dtype=torch.float32, device=state.device)
        return rasterize(
            m.means, m.quats, m.scales, m.opacities, m.rgb, T_cam_world, K,
            intrinsics.width, intrinsics.height, backend=state.backend, cull=True,
            low_pass=zoom_low_pass(state, intrinsics),
        )  # fmt: skip
    return rasterize(
        m.means,
        m.quats,
        m.scales,
        m.opacities,
        m.rgb,
        T_cam_world,
        state.K,
        state.intrinsics.width,
        state.intrinsics.height,
        backend=state.backend,
        cull=True,
    )


def zoom_low_pass(state: MapState, intrinsics: CameraIntrinsics) -> float:
    """The screen dilation (px^2) for rendering at ``intrinsics``: ``0.3 z^2`` for a camera ``z`` times
    finer than the mapper's (``z = fx / fx_mapper`` > 1) when ``mapper.zoom_low_pass`` is on, else 0.3.

    The map was fitted with 0.3 px^2 at the mapper's pixels; rendered 4x finer with the same 0.3 px^2
    its small Gaussians turn into sharp, aliased splats (Mip-Splatting's zoom-in artefact). Scaling the
    dilation keeps each splat's footprint in the scene what it was in training (docs/mapping.md).
    """
    zoom = float(intrinsics.fx) / float(state.intrinsics.fx)
    if not state.cfg.zoom_low_pass or zoom <= 1.0:
        return LOW_PASS
    return LOW_PASS * zoom * zoom


def render_pose(
    state: MapState, T_world_cam: np.ndarray, intrinsics: CameraIntrinsics | None = None
) -> RenderOutput:
    """Render the map (no gradients) from a (rigid or Sim(3)) ``T_world_cam`` [4, 4] (``intrinsics``:
    another camera than the mapper's, e.g. the input at full resolution)."""
    R, t, _ = split_sim3(np.asarray(T_world_cam, dtype=np.float64))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R.T, -R.T @ t
    with torch.no_grad():
        T_cw = torch.as_tensor(T, dtype=torch.float32, device=state.device)
        return render(state, T_cw, intrinsics=intrinsics)


@torch.no_grad()
def render_keyframe(state: MapState, index: int) -> RenderOutput:
    """Render a keyframe (with its refined pose) at the mapper resolution."""
    return render(state, state.keyframe(index).T_cam_world(state.device))


def refined_poses(state: MapState) -> dict[int, np.ndarray]:
    """``T_world_cam`` [4, 4] of every keyframe with its refinement applied (Sim(3) scale kept)."""
    return {i: state.keyframes[i].refined_pose() for i in state.order}
