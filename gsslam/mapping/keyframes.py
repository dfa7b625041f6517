"""Mapper keyframes: image, depth and pose at the mapper resolution, plus the small helpers around them.

A :class:`Keyframe` holds the rigid part of the given ``T_world_cam`` (``R``, ``t``), its Sim(3)
scale, and an se(3) right-perturbation ``delta`` that pose refinement optimizes
(``T_world_cam_refined = T_world_cam @ D(delta)``, :func:`gsslam.mapping.pose.se3_delta_matrix`).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import cv2
import numpy as np
import torch

from gsslam.config import MapperConfig
from gsslam.errors import GsslamError
from gsslam.geometry import split_sim3
from gsslam.mapping.pose import se3_delta_matrix
from gsslam.types import Frame


class MapperError(GsslamError):
    """The mapper was given inconsistent input (unknown keyframe, wrong array shapes, bad device)."""


@dataclass
class Keyframe:
    index: int
    submap_id: int
    image: torch.Tensor  # [h, w, 3] at mapper resolution
    depth: torch.Tensor  # [h, w] world units, NaN unknown
    R: np.ndarray  # [3, 3] rigid rotation of T_world_cam
    t: np.ndarray  # [3]
    scale: float  # Sim(3) scale of the given pose (submap units -> world)
    delta: torch.Tensor  # [6] se(3) right-perturbation (rho, phi), optimized
    anchor: torch.Tensor  # [6] where the pose prior pulls delta: 0, or the accepted pose-only refinement
    depth_weight: torch.Tensor | None = None  # [h, w] confidence of ``depth`` in [0, 1] (None: all 1)
    exposure: torch.Tensor | None = None  # [2, 3] log gain, bias per channel; None: identity

    @property
    def median_depth(self) -> float:  # world units; sets the translation scale of the pose prior
        d = self.depth[torch.isfinite(self.depth)]
        return float(d.median()) if d.numel() else 1.0

    def T_cam_world(self, device: torch.device, with_delta: bool = True) -> torch.Tensor:  # [4, 4]
        """The rigid world-to-camera transform (with the refinement delta unless ``with_delta=False``)."""
        T_wc = torch.eye(4, dtype=torch.float32, device=device)
        T_wc[:3, :3] = torch.as_tensor(self.R, dtype=torch.float32, device=device)
        T_wc[:3, 3] = torch.as_tensor(self.t, dtype=torch.float32, device=device)
        if with_delta:
            T_wc = T_wc @ se3_delta_matrix(self.delta)
        R, t = T_wc[:3, :3], T_wc[:3, 3]
        top = torch.cat([R.T, -(R.T @ t)[:, None]], dim=1)
        return torch.cat([top, torch.tensor([[0.0, 0.0, 0.0, 1.0]], device=device)], dim=0)

    def refined_pose(self) -> np.ndarray:  # [4, 4] Sim(3) T_world_cam with the delta applied
        D = se3_delta_matrix(self.delta.detach().cpu().double()).numpy()
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.R, self.t
        T = T @ D
        T[:3, :3] *= self.scale
        return T


def make_keyframe(
    cfg: MapperConfig,
    frame: Frame,
    T_world_cam: np.ndarray,  # [4, 4] SE(3) or Sim(3)
    submap_id: int,
    size: tuple[int, int],  # (w, h) mapper resolution
    device: torch.device,
    points_cam: np.ndarray | None = None,  # [H, W, 3] in submap units (NaN unknown)
    confidence: np.ndarray | None = None,  # [H, W] in [0, 1]
) -> Keyframe:
    """Resize image and depth (point-map z or sensor depth, times the pose's scale) to ``size``."""
    T = np.asarray(T_world_cam, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise MapperError(f"frame {frame.index}: T_world_cam must be a finite 4x4, got {T.shape}")
    R, t, s = split_sim3(T)
    w, h = size
    weight = None
    image = resize(frame.image.astype(np.float32), w, h)
    if points_cam is not None:
        if points_cam.ndim != 3 or points_cam.shape[2] != 3:
            raise MapperError(f"frame {frame.index}: points_cam must be [h, w, 3], got {points_cam.shape}")
        depth = resize(points_cam[..., 2].astype(np.float32), w, h, nearest=True) * s
        if confidence is not None:
            conf = resize(confidence.astype(np.float32), w, h, nearest=True)
            depth = np.where(conf >= cfg.min_confidence, depth, np.nan)
            if cfg.depth_confidence_weight:
                weight = torch.as_tensor(np.clip(conf, 0.0, 1.0), device=device)
    elif frame.depth is not None:
        depth = resize(frame.depth.astype(np.float32), w, h, nearest=True) * s
    else:
        raise MapperError(f"frame {frame.index}: need points_cam or a frame with depth to seed Gaussians")
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan).astype(np.float32)
    return Keyframe(
        index=frame.index,
        submap_id=int(submap_id),
        image=torch.as_tensor(image, device=device),
        depth=torch.as_tensor(depth, device=device),
        R=R,
        t=t,
        scale=s,
        delta=torch.zeros(6, device=device),
        anchor=torch.zeros(6, device=device),
        depth_weight=weight,
    )


def resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise MapperError("mapper.device=cuda but torch sees no CUDA device; use mapper.device=auto or cpu")
    if name not in ("cpu", "cuda"):
        raise MapperError(f"mapper.device must be auto, cpu or cuda, got {name!r}")
    return torch.device(name)


def resize(a: np.ndarray, w: int, h: int, nearest: bool = False) -> np.ndarray:
    if a.shape[1] == w and a.shape[0] == h:
        return a
    interp = cv2.INTER_NEAREST if nearest else cv2.INTER_AREA
    return cv2.resize(a, (w, h), interpolation=interp)


def fill_depth(depth: torch.Tensor) -> torch.Tensor:  # [h, w] NaN holes -> [h, w] filled
    """Depth holes (no sensor / point-map value) filled by inpainting, so they still get Gaussians.

    Those Gaussians carry colour only: the depth losses ignore pixels without a measured depth.
    """
    d = depth.detach().cpu().numpy()
    hole = ~np.isfinite(d)
    if not hole.any() or hole.all():
        return depth
    filled = cv2.inpaint(
        np.nan_to_num(d, nan=0.0).astype(np.float32), hole.astype(np.uint8), 3, cv2.INPAINT_NS
    )
    return torch.as_tensor(np.where(hole, filled, d), device=depth.device)


@contextmanager
def torch_threads(n: int) -> Iterator[None]:
    """Run the block with ``n`` torch CPU threads (``n <= 0``: unchanged), then restore the setting.

    The CPU rasterizer's threads spin when the cores are shared (tracking, other processes): one
    thread was up to 15x faster than two on a busy 2-core machine (docs/mapping.md, "Threads").
    """
    before = torch.get_num_threads()
    if n > 0 and n != before:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        if torch.get_num_threads() != before:
            torch.set_num_threads(before)


def available_cores() -> int:
    """CPU cores this process may run on (its affinity mask; ``os.cpu_count()`` where there is none)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def end_threads(n: int) -> int:
    """Threads of the end-of-run passes (``mapper.final_num_threads``): ``n``, or every available core
    for ``n <= 0``. Nothing else runs then (tracking, loops and frame prefetching are over), so the
    threads do not compete with the run's own work as ``mapper.num_threads`` must during it."""
    return n if n > 0 else available_cores()
