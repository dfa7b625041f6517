"""Keyframe selection by optical-flow magnitude (GaussianFlow / SING3R front-end).

A frame becomes a keyframe when the median flow magnitude from the last keyframe reaches
``cfg.min_flow_px`` (full-resolution pixels), or when ``cfg.max_gap`` frames have passed.
Flow that is non-finite almost everywhere (e.g. a black frame) never triggers a keyframe by
itself; only the gap does.
"""

from __future__ import annotations

import logging

import numpy as np

from gsslam.config import KeyframeConfig
from gsslam.errors import GsslamError

log = logging.getLogger(__name__)


class KeyframeError(GsslamError):
    """The keyframe config or the flow handed to the selector is unusable."""


MEDIAN_STRIDE = 4  # the median is taken over every 4th pixel in u and v (1/16 of them)


def median_flow_magnitude(
    flow: np.ndarray,  # [H, W, 2]
    valid: np.ndarray | None = None,  # [H, W] bool
    stride: int = MEDIAN_STRIDE,
) -> float:
    """Median ``|flow|`` over finite (and ``valid``) pixels of a ``stride`` grid; NaN when there are none.

    Dense flow is smooth at the scale of a few pixels (and computed at half resolution or less),
    so a strided grid gives the same median as all pixels at a fraction of the cost.
    """
    if flow.ndim != 3 or flow.shape[2] != 2:
        raise KeyframeError(f"flow must be [H, W, 2], got {flow.shape}")
    if stride < 1:
        raise KeyframeError(f"stride must be >= 1, got {stride}")
    flow = flow[::stride, ::stride]
    if valid is not None:
        valid = valid[::stride, ::stride]
    mag = np.hypot(flow[..., 0], flow[..., 1])
    ok = np.isfinite(mag) if valid is None else np.isfinite(mag) & valid
    return float(np.median(mag[ok])) if ok.any() else float("nan")


class KeyframeSelector:
    def __init__(self, cfg: KeyframeConfig) -> None:
        if cfg.max_gap < 1:
            raise KeyframeError(f"keyframes.max_gap must be >= 1, got {cfg.max_gap}")
        if cfg.min_flow_px <= 0:
            raise KeyframeError(f"keyframes.min_flow_px must be > 0, got {cfg.min_flow_px}")
        self.cfg = cfg

    def is_keyframe(
        self,
        flow_from_last_kf: np.ndarray,  # [H, W, 2] flow last keyframe -> this frame, full resolution px
        frames_since_kf: int,
        valid: np.ndarray | None = None,  # [H, W] bool, e.g. forward-backward consistent pixels
    ) -> bool:
        if frames_since_kf >= self.cfg.max_gap:
            return True
        if frames_since_kf < 1:
            return False
        mag = median_flow_magnitude(flow_from_last_kf, valid)
        if not np.isfinite(mag):
            log.debug("keyframe test: no finite flow; waiting for the max_gap rule")
            return False
        return mag >= self.cfg.min_flow_px
