"""A folder of images (sorted by file name) or a video file, with user-given intrinsics.

- ``path``: a folder (every ``.png/.jpg/.jpeg/.bmp/.tif/.tiff/.ppm/.pgm`` file, sorted by name) or
  a video file read with ``cv2.VideoCapture`` (frames decoded on demand; sequential access is cheap,
  jumping backwards re-seeks).
- Intrinsics, first that is given: ``intrinsics=CameraIntrinsics``; ``intrinsics_file=`` a YAML
  file with ``fx, fy, cx, cy`` and optional ``distortion: [k1, k2, p1, p2[, k3]]``, ``fps``,
  ``width``, ``height`` (size defaults to the first image's), or a ROS camera_info YAML
  (``camera_matrix.data``, ``distortion_coefficients.data``, ``image_width/height``); or the kwargs
  ``fx, fy, cx, cy`` (+ ``distortion``). Distorted images are undistorted once; frames carry the same
  K, no distortion.
- Timestamps ``index / fps``: ``fps=`` kwarg, else the YAML's ``fps``, else the video's own rate,
  else 30.
- No depth, no ground truth (``ground_truth()`` is ``None``).
"""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np

from gsslam.datasets.base import DatasetError
from gsslam.datasets.common import load_intrinsics_yaml, normalize_index, read_yaml_mapping
from gsslam.datasets.image_io import (
    IMAGE_SUFFIXES,
    Undistorter,
    check_image_files,
    read_color,
    to_rgb_float,
)
from gsslam.types import CameraIntrinsics, Frame, Trajectory

log = logging.getLogger(__name__)

DEFAULT_FPS = 30.0
_YAML_EXAMPLE = (
    "{fx: 525.0, fy: 525.0, cx: 319.5, cy: 239.5} (optional: distortion: [k1, k2, p1, p2], fps: 30)"
)


class ImagesError(DatasetError):
    """An image folder or video cannot be read, or its intrinsics are missing."""


class _Video:
    """Random access into a video, cheap when frames are asked for in order."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._cap: cv2.VideoCapture | None = None
        self._next = 0
        cap = cv2.VideoCapture(str(path))
        if not cap.isOpened():
            raise ImagesError(f"cannot open video {path}; is it a video file OpenCV can decode?")
        self.count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        self.fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        ok, first = cap.read()
        cap.release()
        if not ok or first is None:
            raise ImagesError(f"video {path} has no decodable frame; the sequence is empty")
        self.width, self.height = int(first.shape[1]), int(first.shape[0])
        if self.count <= 0:
            raise ImagesError(
                f"video {path} does not report its frame count; convert it to a folder of images"
            )

    def read(self, i: int) -> np.ndarray:
        if self._cap is None:
            self._cap = cv2.VideoCapture(str(self.path))
            self._next = 0
        if i != self._next:
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, i)
        ok, img = self._cap.read()
        if not ok or img is None:
            raise ImagesError(f"cannot decode frame {i} of video {self.path} ({self.count} frames reported)")
        self._next = i + 1
        return img


def _yaml_fps(path: Path) -> float | None:
    fps = read_yaml_mapping(path, "intrinsics file", "fx, fy, cx, cy").get("fps")
    if fps is None:
        return None
    try:
        value = float(fps)
    except (TypeError, ValueError):
        raise ImagesError(f"intrinsics file {path}: fps must be a number, got {fps!r}") from None
    if not (np.isfinite(value) and value > 0):
        raise ImagesError(f"intrinsics file {path}: fps must be a positive number, got {fps!r}")
    return value


class ImageSequenceDataset:
    """Images of a folder or frames of a video; see the module docstring for the kwargs."""

    def __init__(
        self,
        path: str | Path,
        *,
        intrinsics: CameraIntrinsics | None = None,
        intrinsics_file: str | Path | None = None,
        fx: float | None = None,
        fy: float | None = None,
        cx: float | None = None,
        cy: float | None = None,
        distortion: tuple[float, ...] | list[float] = (),
        fps: float | None = None,
    ) -> None:
        self.root = Path(path)
        self.name = self.root.stem
        self.has_depth = False
        self._video: _Video | None = None
        self._files: list[Path] = []
        if self.root.is_dir():
            self._files = sorted(p for p in self.root.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
            if not self._files:
                raise ImagesError(
                    f"{self.root} holds no images ({', '.join(IMAGE_SUFFIXES)}); the sequence is empty"
                )
            # headers only: a file of another size is refused now, not when the run reaches it
            width, height = check_image_files(self._files, None, "image")
            source_fps = None
        elif self.root.is_file():
            self._video = _Video(self.root)
            width, height, source_fps = self._video.width, self._video.height, self._video.fps or None
        else:
            raise ImagesError(f"image folder or video does not exist: {self.root}")

        yaml_fps = None
        if intrinsics is None and intrinsics_file is not None:
            intrinsics = load_intrinsics_yaml(Path(intrinsics_file), width, height)
            yaml_fps = _yaml_fps(Path(intrinsics_file))
        if intrinsics is None and None not in (fx, fy, cx, cy):
            intrinsics = CameraIntrinsics(fx, fy, cx, cy, width, height, tuple(float(d) for d in distortion))
        if intrinsics is None:
            raise ImagesError(
                f"{self.root}: intrinsics are needed; pass intrinsics_file= (CLI: --intrinsics) "
                "with a YAML mapping like: " + _YAML_EXAMPLE
            )
        if (intrinsics.width, intrinsics.height) != (width, height):
            raise ImagesError(
                f"intrinsics are for {intrinsics.width}x{intrinsics.height} "
                f"but the images are {width}x{height}; "
                "fix width/height (or fx, fy, cx, cy) in the intrinsics"
            )
        self._undistort = Undistorter(intrinsics)
        self.intrinsics = self._undistort.intrinsics_out
        self.fps = float(fps or yaml_fps or source_fps or DEFAULT_FPS)
        if self.fps <= 0:
            raise ImagesError(f"fps must be positive, got {self.fps}")
        log.info("images %s: %d frames at %.3g fps", self.root, len(self), self.fps)

    def __len__(self) -> int:
        return self._video.count if self._video is not None else len(self._files)

    def timestamps(self) -> list[float]:
        return [i / self.fps for i in range(len(self))]

    def __getitem__(self, index: int) -> Frame:
        i = normalize_index(index, len(self))
        if self._video is not None:
            image = to_rgb_float(self._video.read(i), f"{self.root} frame {i}")
        else:
            image = read_color(self._files[i])
        image = self._undistort.image(image)
        return Frame(i, i / self.fps, image, self.intrinsics)

    def ground_truth(self) -> Trajectory | None:
        return None

    def ground_truth_at_frames(self) -> Trajectory | None:
        return None
