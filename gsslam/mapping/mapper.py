"""The Gaussian mapper: keyframes in, a 3D Gaussian map (and refined keyframe poses) out.

SING3R-SLAM's global map stage plus GaussianFlow's flow supervision, one window at a time:

1. :meth:`GaussianMapper.add_keyframe` resizes the frame to the mapper resolution (``max_side``),
   renders the current map there and seeds new Gaussians only where the map is unmapped (rendered
   alpha < ``unmapped_alpha``, or the measured surface lies well in front of the rendered one), from the
   submap point map (or the sensor depth), coloured by the image, sized by the pixel footprint.
2. :meth:`GaussianMapper.optimize` runs Adam over the last ``window`` keyframes: colour L1+SSIM,
   inverse-depth L1, depth-normal consistency, scale regularizer, GaussianFlow flow loss on stored
   keyframe pairs, and (intra-submap pose refinement) photometric L1 under the alpha mask plus the
   scale-invariant depth term w.r.t. se(3) deltas on the keyframe poses; then densify/prune
   (:mod:`gsslam.mapping.densify`).
3. :meth:`GaussianMapper.on_poses_updated` moves the Gaussians of submaps the pose graph moved.

The class is a facade: it owns one :class:`~gsslam.mapping.state.MapState` (model, densification
state, keyframes, flows, random generators) and passes it to the stages, plain functions that each live
in their own module: :mod:`~gsslam.mapping.keyframes` (keyframe records and resizing),
:mod:`~gsslam.mapping.seeding`, :mod:`~gsslam.mapping.pose_refine`, :mod:`~gsslam.mapping.window`
(the optimization step), :mod:`~gsslam.mapping.final_pass` and :mod:`~gsslam.mapping.outputs`
(metrics, PLY, panels). No stage imports this module.

Keyframe poses ``T_world_cam`` may be Sim(3) (the scale maps submap units to world units); the camera
itself is the rigid part. All depths the mapper returns are z-depths in world units.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
import torch

from gsslam.config import MapperConfig
from gsslam.geometry import invert_T, split_sim3
from gsslam.mapping import exposure as X
from gsslam.mapping import final_pass, outputs
from gsslam.mapping.converged import converged_owners, covered_depths
from gsslam.mapping.densify import DensifyStrategy
from gsslam.mapping.gaussians import GaussianModel
from gsslam.mapping.keyframes import MapperError, make_keyframe, resize, resolve_device, torch_threads
from gsslam.mapping.pose_refine import refine_pose
from gsslam.mapping.rasterize import RenderOutput, resolve_backend
from gsslam.mapping.registration import Registration, register
from gsslam.mapping.seeding import seed_gaussians
from gsslam.mapping.state import MapState, refined_poses, render_keyframe, render_pose
from gsslam.mapping.window import optimize_window
from gsslam.types import CameraIntrinsics, Frame

__all__ = ["GaussianMapper", "MapperError", "torch_threads"]

_log = logging.getLogger(__name__)


class GaussianMapper:
    """A window-optimized 3D Gaussian map over keyframes; see the module docstring."""

    def __init__(self, cfg: MapperConfig, intrinsics: CameraIntrinsics) -> None:
        if not 0.0 <= cfg.revisit_fraction <= 1.0:
            raise MapperError(f"mapper.revisit_fraction must lie in [0, 1], got {cfg.revisit_fraction}")
        self.cfg = cfg
        self.device = resolve_device(cfg.device)
        self.full_intrinsics = intrinsics
        factor = min(1.0, cfg.max_side / max(intrinsics.width, intrinsics.height))
        self.intrinsics = intrinsics.scaled(factor)
        self.factor_x = self.intrinsics.width / intrinsics.width
        self.factor_y = self.intrinsics.height / intrinsics.height
        self.K = torch.tensor(self.intrinsics.K, dtype=torch.float32, device=self.device)
        strategy = DensifyStrategy(
            densify_error=cfg.densify_error,
            prune_error=cfg.prune_error,
            min_opacity=cfg.min_opacity,
            max_gaussians=cfg.max_gaussians,
        )
        self.map = MapState(
            cfg=cfg,
            device=self.device,
            intrinsics=self.intrinsics,
            K=self.K,
            strategy=strategy,
            model=GaussianModel.empty(self.device),
            densify_state=strategy.initialize_state(0, self.device),
            backend=resolve_backend(cfg.rasterizer, self.device),
        )
        self._submap_poses: dict[int, np.ndarray] = {}  # submap id -> T_world_submap the map follows

    # ------------------------------------------------------------------ properties
    @property
    def rasterizer_backend(self) -> str:
        """``"c"`` | ``"torch"`` | ``"gsplat"``: what every render of this mapper uses (in metrics.json)."""
        return self.map.backend

    @property
    def model(self) -> GaussianModel:
        return self.map.model

    @property
    def num_gaussians(self) -> int:
        return len(self.map.model)

    @property
    def size_mb(self) -> float:
        return self.map.model.size_bytes() / 1e6

    @property
    def keyframe_indices(self) -> list[int]:
        return list(self.map.order)

    # ------------------------------------------------------------------ poses
    def refined_poses(self) -> dict[int, np.ndarray]:
        """``T_world_cam`` [4, 4] of every keyframe with its refinement applied (Sim(3) scale kept)."""
        return refined_poses(self.map)

    # ------------------------------------------------------------------ rendering
    def render_pose(self, T_world_cam: np.ndarray) -> RenderOutput:
        """Render the map (no gradients) at the mapper resolution from a (rigid or Sim(3)) pose."""
        return render_pose(self.map, T_world_cam)

    # ------------------------------------------------------------------ input
    def add_keyframe(
        self,
        frame: Frame,
        T_world_cam: np.ndarray,  # [4, 4] SE(3) or Sim(3)
        submap_id: int,
        points_cam: np.ndarray | None = None,  # [h, w, 3] in submap units (NaN unknown)
        confidence: np.ndarray | None = None,  # [h, w] in [0, 1]
    ) -> int:
        """Register a keyframe and seed Gaussians in its unmapped pixels; returns how many were added."""
        st = self.map
        size = (self.intrinsics.width, self.intrinsics.height)
        kf = make_keyframe(self.cfg, frame, T_world_cam, submap_id, size, self.device, points_cam, confidence)
        if self.cfg.exposure and st.order and st.order[0] != frame.index:  # start at the nearest keyframe's
            e = outputs.frame_exposure(st, frame.index)
            kf.exposure = X.identity(self.device) if e is None else e.detach().clone()
        if frame.index not in st.keyframes:
            st.order.append(frame.index)
        st.keyframes[frame.index] = kf
        with torch_threads(self.cfg.num_threads):
            if self.cfg.pose_refinement and len(st.model) and frame.index != st.order[0]:
                self.refine_pose(frame.index, self.cfg.pose_iterations)
            return seed_gaussians(st, kf)

    def refine_pose(self, frame_index: int, iterations: int) -> float:
        """Intra-submap pose refinement of one keyframe against the frozen map; returns the last loss.

        See :func:`gsslam.mapping.pose_refine.refine_pose`.
        """
        return refine_pose(self.map, self.map.keyframe(frame_index), iterations)

    def register(
        self,
        frame: Frame,
        T_world_cam: np.ndarray,  # [4, 4] SE(3) or Sim(3): where the graph puts the frame now
        points_cam: np.ndarray | None = None,  # [h, w, 3] in submap units (NaN unknown)
        confidence: np.ndarray | None = None,  # [h, w] in [0, 1]
    ) -> Registration | None:
        """Register a frame that is not (yet) in the map against it; None where the map cannot tell.

        See :func:`gsslam.mapping.registration.register`. The map and its keyframes are unchanged.
        """
        if not len(self.map.model):
            return None
        size = (self.intrinsics.width, self.intrinsics.height)
        kf = make_keyframe(self.cfg, frame, T_world_cam, -1, size, self.device, points_cam, confidence)
        kf.exposure = outputs.frame_exposure(self.map, frame.index)  # the nearest keyframe's (None: identity)
        with torch_threads(self.cfg.num_threads):
            return register(self.map, kf, self.cfg.registration_iterations)

    def registration_owners(self, T_world_cam: np.ndarray) -> dict[int, float]:
        """Submap id -> share of the converged map's rendered weight at ``T_world_cam`` [4, 4] (a registered
        pose): which submaps own what it was registered against (:func:`converged_owners`)."""
        with torch_threads(self.cfg.num_threads):
            return converged_owners(self.map, T_world_cam)

    def add_flow(
        self,
        frame_a_index: int,
        frame_b_index: int,
        flow: np.ndarray,  # [H, W, 2] full-resolution pixels, a -> b
        valid: np.ndarray,  # [H, W] bool
    ) -> None:
        """Store dense flow between two keyframes (rescaled to the mapper resolution) for the flow loss."""
        self.map.keyframe(frame_a_index), self.map.keyframe(frame_b_index)
        H, W = self.full_intrinsics.height, self.full_intrinsics.width
        if flow.shape != (H, W, 2) or valid.shape != (H, W):
            raise MapperError(
                f"flow must be [{H}, {W}, 2] and valid [{H}, {W}], got {flow.shape}, {valid.shape}"
            )
        w, h = self.intrinsics.width, self.intrinsics.height
        f = resize(np.nan_to_num(flow.astype(np.float32)), w, h)
        f = f * np.array([self.factor_x, self.factor_y], dtype=np.float32)
        v = resize(valid.astype(np.float32), w, h) > 0.99
        self.map.flows[(frame_a_index, frame_b_index)] = (
            torch.as_tensor(f, device=self.device),
            torch.as_tensor(v, device=self.device),
        )

    # ------------------------------------------------------------------ graph feedback
    def on_poses_updated(
        self, submap_poses: dict[int, np.ndarray], keyframe_poses: dict[int, np.ndarray]
    ) -> int:
        """Follow the pose graph: move Gaussians of moved submaps, reset keyframe poses.

        ``submap_poses``: Sim(3) ``T_world_submap`` [4, 4] per submap id. The first time a submap id
        appears its transform is recorded as the reference; afterwards Gaussians anchored to it move by
        ``T_new @ T_old^-1``. ``keyframe_poses``: new ``T_world_cam`` per keyframe index (their pose
        deltas are reset: the graph is expected to have absorbed :meth:`refined_poses`).
        Returns the number of Gaussians moved.
        """
        moved = 0
        for sid, T_new in submap_poses.items():
            T_new = np.asarray(T_new, dtype=np.float64)
            T_old = self._submap_poses.get(sid)
            self._submap_poses[sid] = T_new.copy()
            if T_old is None or np.allclose(T_old, T_new, atol=1e-9):
                continue
            moved += self.map.model.apply_transform(sid, T_new @ invert_T(T_old))
        for idx, T in keyframe_poses.items():
            if idx not in self.map.keyframes:
                continue
            kf = self.map.keyframes[idx]
            R, t, s = split_sim3(np.asarray(T, dtype=np.float64))
            if abs(s - kf.scale) > 1e-9:
                kf.depth = kf.depth * (s / kf.scale)
            kf.R, kf.t, kf.scale = R, t, s
            kf.delta = torch.zeros(6, device=self.device)
            kf.anchor = torch.zeros(6, device=self.device)
        return moved

    # ------------------------------------------------------------------ optimization
    def optimize(self, iterations: int | None = None) -> dict:
        """Sliding-window optimization; see :func:`gsslam.mapping.window.optimize_window`."""
        return optimize_window(self.map, iterations)

    def finalize(
        self,
        iterations: int | None = None,
        progress: Callable[[int, int], None] | None = None,
        step_seconds: float = 0.0,
        run_seconds: float = 0.0,
    ) -> dict:
        """End-of-run pass over all keyframes; see :func:`gsslam.mapping.final_pass.finalize`."""
        return final_pass.finalize(self.map, iterations, progress, step_seconds, run_seconds)

    def refine_joint(self, iterations: int | None = None) -> dict:
        """Final joint pose+map refinement; see :func:`gsslam.mapping.final_pass.refine_joint`.

        Afterwards :meth:`refined_poses` holds the refined keyframe poses.
        """
        return final_pass.refine_joint(self.map, iterations)

    def render_keyframe(self, frame_index: int) -> RenderOutput:
        """Render a keyframe (with its refined pose) at the mapper resolution."""
        return render_keyframe(self.map, frame_index)

    def keyframe_image(self, frame_index: int) -> np.ndarray:  # [h, w, 3] at the mapper resolution
        return self.map.keyframe(frame_index).image.cpu().numpy()

    def rendered_depth(self, frame_index: int) -> np.ndarray:
        """Rendered z-depth [H, W] at full resolution, world units, NaN where the map is empty."""
        out = self.render_keyframe(frame_index)
        d = torch.where(out.alpha > 0.5, out.depth, torch.full_like(out.depth, float("nan")))
        W, H = self.full_intrinsics.width, self.full_intrinsics.height
        return resize(d.cpu().numpy().astype(np.float32), W, H, nearest=True)

    def depth_feedback(
        self, frame_index: int, n_points: int, T_world_cam: np.ndarray | None = None, min_alpha: float = 0.95
    ) -> tuple[np.ndarray, np.ndarray]:
        """Up to ``n_points`` well-covered pixels of a keyframe: (uv [N, 2] full-res px, depth [N] world).

        With ``T_world_cam`` [4, 4] the map is rendered from that pose instead (a frame not in the map).
        """
        out = self.render_keyframe(frame_index) if T_world_cam is None else self.render_pose(T_world_cam)
        uv, depth = covered_depths(out, n_points, self.map.rng, min_alpha)
        return self.full_res_uv(uv), depth

    def full_res_uv(self, uv: np.ndarray) -> np.ndarray:
        """Pixel centres [N, 2] at the mapper resolution -> the same points at the input resolution."""
        return np.stack(
            [(uv[:, 0] + 0.5) / self.factor_x - 0.5, (uv[:, 1] + 0.5) / self.factor_y - 0.5], axis=1
        )

    def evaluate(
        self,
        frames: Iterable[Frame],
        poses: dict[int, np.ndarray],
        native: bool = False,
        progress: Callable[[int], None] | None = None,
        native_only: set[int] | None = None,
    ) -> dict:
        """PSNR / SSIM of keyframes and held-out frames with a pose, at the mapper resolution and, with
        ``native``, also at the input's (``*_native``); see :func:`gsslam.mapping.outputs.evaluate_map`."""
        with final_pass.end_of_run_threads(self.cfg):
            intr = self.full_intrinsics if native else None
            return outputs.evaluate_map(self.map, frames, poses, intr, progress, native_only)

    def native_panel(self, frame: Frame, T_world_cam: np.ndarray, path: str | Path) -> Path:
        """``input | render | depth`` of ``frame`` at the input resolution (where the map is weak)."""
        with final_pass.end_of_run_threads(self.cfg):
            return outputs.native_panel(self.map, frame, T_world_cam, self.full_intrinsics, path)

    def save_ply(self, path: str | Path) -> int:
        """Write the map as a 3DGS PLY; returns the file size in bytes."""
        return outputs.save_map_ply(self.map.model, path)

    def render_keyframe_panels(self, out_dir: str | Path, n: int = 4) -> list[Path]:
        """Write ``n`` PNGs, input | render | depth (turbo colour map), for keyframes spread over the run."""
        return outputs.keyframe_panels(self.map, out_dir, n)
