"""Keyframe images of a run, saved next to its trajectory so that exports need no dataset.

``keyframes/<timestamp>.jpg``: the undistorted colour image the pipeline saw for every keyframe of
``keyframes.tum`` (same timestamp text, JPEG quality 95), matching ``intrinsics.yaml``. Saving them
in the run (instead of re-reading the dataset at export time) keeps a run folder self-contained:
exports work after the dataset moved, for videos and bags, and with no loader options to replay.
"""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np

log = logging.getLogger(__name__)

KEYFRAME_DIR = "keyframes"
JPEG_QUALITY = 95


def timestamp_name(t: float) -> str:
    """The file stem of a keyframe image: the timestamp as written in TUM files (shortest exact text)."""
    return np.format_float_positional(float(t), unique=True, trim="-")


def save_keyframe_images(ds, keyframes: dict[int, float], folder: str | Path) -> int:
    """Write ``ds[i].image`` for each ``{frame index: timestamp}`` as ``folder/<timestamp>.jpg``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for i, t in sorted(keyframes.items()):
        img = (np.clip(ds[i].image, 0, 1) * 255 + 0.5).astype(np.uint8)  # [H, W, 3] RGB
        cv2.imwrite(
            str(folder / f"{timestamp_name(t)}.jpg"), img[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY]
        )
    log.debug("saved %d keyframe images to %s", len(keyframes), folder)
    return len(keyframes)


def find_keyframe_images(folder: str | Path) -> dict[float, Path]:
    """``{timestamp: path}`` of the images in a run's ``keyframes/`` folder (empty when absent)."""
    out = {}
    for p in sorted(Path(folder).glob("*.jpg")) if Path(folder).is_dir() else []:
        try:
            out[float(p.stem)] = p
        except ValueError:
            continue
    return out
