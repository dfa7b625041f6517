"""Reading images and depth maps from disk, and undistorting them once, for every loader.

- :func:`read_color` gives ``[H, W, 3]`` float32 RGB in [0, 1]; grayscale files are replicated to
  three channels; 16-bit files are scaled by 1/65535.
- :func:`read_depth` gives ``[H, W]`` float32 metres (raw value / ``scale``) with invalid raw values
  (0 by default) set to NaN. 8-bit depth files are refused: 256 levels cannot hold a depth range
  (a depth map saved as an 8-bit PNG has lost its units).
- :func:`check_image_files` reads only the headers of a sequence's files and refuses, before a run
  starts, a file whose size differs from the camera's (or an 8-bit depth file), naming the file.
- :class:`Undistorter` removes lens distortion with OpenCV maps computed once per camera. The
  undistorted image keeps the same pinhole matrix K (``newCameraMatrix = K``), so the frames a loader
  hands out have the dataset's K with ``distortion == ()``. Colour is resampled bilinearly, depth
  with nearest neighbour (no mixing of depths across edges); pixels that map outside the source
  image become black (colour) or NaN (depth).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from gsslam.datasets.base import DatasetError
from gsslam.types import CameraIntrinsics

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm")


class ImageReadError(DatasetError):
    """An image or depth file is missing, unreadable or has an unexpected format."""


def _imread(path: Path) -> np.ndarray:
    path = Path(path)
    if not path.is_file():
        raise ImageReadError(f"image file is missing: {path}")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise ImageReadError(f"cannot decode image {path} (corrupt or not an image); replace the file")
    return img


def image_size(path: Path) -> tuple[int, int]:
    """``(width, height)`` of an image file (decodes it once)."""
    img = _imread(path)
    return int(img.shape[1]), int(img.shape[0])


# Pillow modes of single-channel images with more than 8 bits per pixel (16-bit PNG, 32-bit TIFF)
_DEEP_MODES = ("I;16", "I;16B", "I;16L", "I;16N", "I", "F")


def read_header(path: Path) -> tuple[int, int, str]:
    """``(width, height, mode)`` of an image file from its header only (Pillow mode, e.g. "RGB", "I;16")."""
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        raise ImageReadError(f"image file is missing: {path}")
    try:
        with Image.open(path) as im:
            return int(im.size[0]), int(im.size[1]), str(im.mode)
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError):
        raise ImageReadError(
            f"cannot decode image {path} (corrupt or not an image); replace the file"
        ) from None


def check_image_files(
    paths: list[Path], size: tuple[int, int] | None, what: str, depth: bool = False
) -> tuple[int, int]:
    """Check every file's header before a run: same ``(width, height)`` as ``size`` (default: the first
    file's) and, for ``depth``, a single channel of more than 8 bits. Returns the size."""
    ref = None if size is None else (int(size[0]), int(size[1]))
    first = None
    for path in paths:
        w, h, mode = read_header(path)
        if ref is None:
            ref, first = (w, h), path
        if (w, h) != ref:
            source = f"{Path(first).name} is" if first is not None else "the camera calibration is for"
            raise ImageReadError(
                f"{path} is {w}x{h} but {source} {ref[0]}x{ref[1]}; every {what} of a sequence must have "
                "the camera's size: resize or remove the odd files (or fix the intrinsics)"
            )
        if depth and mode not in _DEEP_MODES:
            kind = "8-bit" if mode in ("L", "P", "1", "LA") else f"a colour image ({mode})"
            raise ImageReadError(_depth_bits_message(path, kind))
    return ref if ref is not None else (0, 0)


def _depth_bits_message(path: Path, kind: str) -> str:
    return (
        f"depth file {path} is {kind}; depth must be a single-channel 16-bit PNG "
        "(raw value / scale = metres): an 8-bit depth map has lost its units; re-export the depth as 16-bit"
    )


def to_rgb_float(img: np.ndarray, source: str = "image") -> np.ndarray:  # -> [H, W, 3] float32
    """Convert a decoded OpenCV array (gray, BGR or BGRA; uint8/uint16/float) to RGB float in [0, 1]."""
    if img.dtype == np.uint8:
        scale = 1.0 / 255.0
    elif img.dtype == np.uint16:
        scale = 1.0 / 65535.0
    elif img.dtype in (np.float32, np.float64):
        scale = 1.0
    else:
        raise ImageReadError(f"{source}: unsupported pixel type {img.dtype}; use 8- or 16-bit images")
    if img.ndim == 2:
        rgb = np.repeat(img[:, :, None], 3, axis=2)
    elif img.ndim == 3 and img.shape[2] == 1:
        rgb = np.repeat(img, 3, axis=2)
    elif img.ndim == 3 and img.shape[2] == 3:
        rgb = img[:, :, ::-1]
    elif img.ndim == 3 and img.shape[2] == 4:
        rgb = img[:, :, 2::-1]
    else:
        raise ImageReadError(f"{source}: unsupported image shape {img.shape}")
    out = np.ascontiguousarray(rgb, dtype=np.float32) * np.float32(scale)
    return np.clip(out, 0.0, 1.0)


def read_color(path: Path) -> np.ndarray:  # -> [H, W, 3] float32 RGB in [0, 1]
    return to_rgb_float(_imread(path), str(path))


def read_depth(path: Path, scale: float, invalid: tuple[int, ...] = (0,)) -> np.ndarray:  # -> [H, W] float32
    """Depth in metres from a 16-bit (or 8/32-bit) single-channel file: ``raw / scale``, NaN where invalid."""
    raw = _imread(path)
    if raw.ndim != 2:
        raise ImageReadError(
            f"depth file {path} has {raw.shape[2]} channels; expected a single-channel image"
        )
    if raw.dtype in (np.uint8, np.int8):
        raise ImageReadError(_depth_bits_message(path, "8-bit"))
    depth = raw.astype(np.float32) / np.float32(scale)
    bad = np.isin(raw, np.asarray(invalid, dtype=raw.dtype)) if invalid else np.zeros(raw.shape, bool)
    depth[bad | ~np.isfinite(depth)] = np.nan
    return depth


class Undistorter:
    """Undistorts images of one camera; ``intrinsics_out`` has the same K and no distortion.

    When ``intrinsics.distortion`` is all zero this is the identity (no resampling at all).
    """

    def __init__(self, intrinsics: CameraIntrinsics) -> None:
        self.intrinsics_in = intrinsics
        self.intrinsics_out = intrinsics.undistorted()
        self.active = intrinsics.has_distortion
        self._maps: tuple[np.ndarray, np.ndarray] | None = None
        if self.active:
            K = intrinsics.K
            D = np.asarray(intrinsics.distortion, dtype=np.float64)
            size = (intrinsics.width, intrinsics.height)
            self._maps = cv2.initUndistortRectifyMap(K, D, None, K, size, cv2.CV_32FC1)

    def _check(self, arr: np.ndarray, what: str) -> None:
        h, w = arr.shape[:2]
        if (w, h) != (self.intrinsics_in.width, self.intrinsics_in.height):
            raise ImageReadError(
                f"{what} is {w}x{h} but the camera calibration is for "
                f"{self.intrinsics_in.width}x{self.intrinsics_in.height}; fix the intrinsics or the images"
            )

    def image(self, img: np.ndarray) -> np.ndarray:  # [H, W, 3] -> [H, W, 3]
        self._check(img, "image")
        if not self.active:
            return img
        m1, m2 = self._maps
        return cv2.remap(img, m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)

    def depth(self, depth: np.ndarray) -> np.ndarray:  # [H, W] -> [H, W], NaN outside
        self._check(depth, "depth map")
        if not self.active:
            return depth
        m1, m2 = self._maps
        out = cv2.remap(
            depth, m1, m2, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=float("nan")
        )
        return out.astype(np.float32)
