"""The submap encoder protocol (SING3R's Sub-Track3R slot) and what its implementations share.

An encoder turns the K+1 keyframes of one submap into a :class:`gsslam.types.SubmapEncoding`:
rigid local poses ``T_local_cam`` (frame 0 = identity), per-frame point maps in each camera's own
frame and a confidence, all at *point-map resolution*: the keyframes are downscaled so that
``max(H, W) <= cfg.pointmap_max_side`` (TUM 640x480 -> 320x240 with the default 320).

Built in: ``"rgbd"`` (:mod:`gsslam.frontend.rgbd_encoder`) and ``"mono"``
(:mod:`gsslam.frontend.mono_encoder`). A learned encoder (CUT3R, MASt3R, ...) plugs in through
:func:`register_encoder`; see docs/frontend.md.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Protocol

import cv2
import numpy as np

from gsslam.config import EncoderConfig
from gsslam.errors import GsslamError
from gsslam.frontend.flow import FlowEstimator
from gsslam.types import CameraIntrinsics, Frame, SubmapEncoding

log = logging.getLogger(__name__)


class EncoderError(GsslamError):
    """Encoder inputs are unusable (too few frames, missing depth for RGB-D, unknown mode)."""


class SubmapEncoder(Protocol):
    def encode(
        self,
        frames: list[Frame],
        shared_depth: np.ndarray | None = None,  # [H, W] or [h, w] depth of frames[0], previous submap units
        shared_pose_hint: np.ndarray | None = None,  # [4, 4] unused by the built-in encoders
        shared_confidence: np.ndarray | None = None,  # [H, W] or [h, w] in [0, 1], of shared_depth
    ) -> SubmapEncoding:
        """Encode K+1 keyframes; ``frames[0]`` is the keyframe shared with the previous submap.

        ``shared_depth`` is the refined depth of ``frames[0]`` in the previous submap's units
        (from the mapper or the previous encoding), at full or point-map resolution. Encoders
        use it to ground the new submap in the latest global geometry; for monocular input it
        also fixes the new submap's scale to the previous one. ``shared_confidence`` is the
        previous submap's confidence in that depth (the mono encoder weights its depth prior by it).
        """
        ...


EncoderFactory = Callable[[EncoderConfig, FlowEstimator], SubmapEncoder]
_FACTORIES: dict[str, EncoderFactory] = {}


def register_encoder(mode: str, factory: EncoderFactory) -> None:
    """Make ``make_encoder(mode, ...)`` build ``factory(cfg, flow)`` (slot for learned encoders)."""
    _FACTORIES[mode] = factory


def make_encoder(mode: str, cfg: EncoderConfig, flow: FlowEstimator) -> SubmapEncoder:
    if "rgbd" not in _FACTORIES or "mono" not in _FACTORIES:
        import importlib

        for name in ("rgbd_encoder", "mono_encoder"):  # importing registers them
            importlib.import_module(f"gsslam.frontend.{name}")
    if mode not in _FACTORIES:
        raise EncoderError(f"unknown encoder mode {mode!r}; choose one of {sorted(_FACTORIES)}")
    return _FACTORIES[mode](cfg, flow)


# ---- helpers shared by the implementations -------------------------------------------------


def check_frames(frames: list[Frame], need_depth: bool) -> None:
    if len(frames) < 2:
        raise EncoderError(f"a submap needs at least 2 keyframes (shared + new), got {len(frames)}")
    shape = frames[0].image.shape
    for f in frames:
        if f.image.shape != shape:
            raise EncoderError(
                f"all keyframes of a submap must have one size; frame {f.index} is "
                f"{f.image.shape[:2]}, frame {frames[0].index} is {shape[:2]}"
            )
        if need_depth and f.depth is None:
            raise EncoderError(
                f"frame {f.index} has no depth; the rgbd encoder needs depth for every "
                f"keyframe (use mode=mono for colour-only input)"
            )


def pointmap_intrinsics(intr: CameraIntrinsics, max_side: int) -> CameraIntrinsics:
    """Intrinsics of the point maps: the image downscaled so that max(H, W) <= max_side."""
    f = min(1.0, max_side / max(intr.width, intr.height))
    return intr if f == 1.0 else intr.scaled(f)


def resize_image(img: np.ndarray, intr: CameraIntrinsics) -> np.ndarray:  # [H, W, 3] -> [h, w, 3]
    if img.shape[:2] == (intr.height, intr.width):
        return img
    return cv2.resize(img, (intr.width, intr.height), interpolation=cv2.INTER_AREA)


def resize_depth(depth: np.ndarray, intr: CameraIntrinsics) -> np.ndarray:  # [H, W] -> [h, w]
    """Nearest-neighbour resize: never blends depths across an object boundary."""
    if depth.shape == (intr.height, intr.width):
        return depth.astype(np.float32)
    return cv2.resize(depth.astype(np.float32), (intr.width, intr.height), interpolation=cv2.INTER_NEAREST)


def depth_edge_mask(depth: np.ndarray, rel_jump: float = 0.05) -> np.ndarray:  # [h, w] -> [h, w] bool
    """Pixels next to a depth discontinuity larger than ``rel_jump * z`` (or next to a hole)."""
    d = np.nan_to_num(depth, nan=0.0).astype(np.float32)
    mx = cv2.dilate(d, np.ones((3, 3), np.uint8))
    mn = cv2.erode(d, np.ones((3, 3), np.uint8))
    with np.errstate(invalid="ignore"):
        return ((mx - mn) > rel_jump * np.maximum(d, 1e-6)) | (mn <= 0)


def robust_depth_stats(depth: np.ndarray) -> dict:  # [h, w] -> dict of floats (NaN-safe)
    z = depth[np.isfinite(depth) & (depth > 0)]
    if len(z) == 0:
        return {"count": 0, "median": float("nan"), "p10": float("nan"), "p90": float("nan")}
    p10, med, p90 = np.percentile(z, [10, 50, 90])
    return {"count": int(len(z)), "median": float(med), "p10": float(p10), "p90": float(p90)}
