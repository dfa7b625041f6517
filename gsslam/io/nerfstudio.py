"""nerfstudio ``transforms.json``: intrinsics, one entry per image with its camera-to-world matrix.

nerfstudio (like instant-ngp and Blender's NeRF data) uses the **OpenGL** camera convention: x right,
y up, the camera looks along -z. gsslam (like OpenCV and COLMAP) uses x right, y down, looking along
+z. So ``transform_matrix = T_world_cam @ diag(1, -1, -1, 1)``; :func:`read_transforms` undoes it.
Intrinsics are written at the top level (``fl_x fl_y cx cy w h``, ``camera_model: OPENCV`` with zero
distortion); ``file_path`` is relative to the JSON file. Extra top-level keys (e.g.
``ply_file_path`` for splatfacto's initial points, or gsslam's units) are passed through ``extra``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gsslam.errors import GsslamError
from gsslam.types import CameraIntrinsics

OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0, 1.0])  # flips y and z of the camera frame (its own inverse)


class NerfstudioError(GsslamError):
    """A transforms.json is missing or malformed."""


@dataclass
class NerfstudioFrame:
    file_path: str
    T_world_cam: np.ndarray  # [4, 4] camera-to-world, OpenCV camera axes (gsslam's convention)


def format_transforms(
    intrinsics: CameraIntrinsics, frames: list[NerfstudioFrame], extra: dict[str, Any] | None = None
) -> str:
    i = intrinsics
    data: dict[str, Any] = {
        "camera_model": "OPENCV",
        "fl_x": float(i.fx),
        "fl_y": float(i.fy),
        "cx": float(i.cx),
        "cy": float(i.cy),
        "w": int(i.width),
        "h": int(i.height),
        "k1": 0.0,
        "k2": 0.0,
        "p1": 0.0,
        "p2": 0.0,
    }
    data.update(extra or {})
    data["frames"] = [
        {
            "file_path": f.file_path,
            "transform_matrix": (np.asarray(f.T_world_cam, dtype=np.float64) @ OPENCV_TO_OPENGL).tolist(),
        }
        for f in frames
    ]
    return json.dumps(data, indent=2) + "\n"


def write_transforms(
    path: str | Path,
    intrinsics: CameraIntrinsics,
    frames: list[NerfstudioFrame],
    extra: dict[str, Any] | None = None,
) -> None:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(format_transforms(intrinsics, frames, extra))


def parse_transforms(
    text: str, source: str = "<string>"
) -> tuple[CameraIntrinsics, list[NerfstudioFrame], dict]:
    """(intrinsics, frames with ``T_world_cam`` in OpenCV axes, the other top-level keys)."""
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise NerfstudioError(f"{source} is not valid JSON: {e}") from None
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list):
        raise NerfstudioError(f"{source}: expected an object with a 'frames' list")
    try:
        intr = CameraIntrinsics(
            float(data["fl_x"]), float(data["fl_y"]), float(data["cx"]), float(data["cy"]),
            int(data["w"]), int(data["h"]),
        )  # fmt: skip
    except KeyError as e:
        raise NerfstudioError(
            f"{source}: missing top-level intrinsics key {e} (per-frame intrinsics are not supported)"
        ) from None
    frames = []
    for k, fr in enumerate(data["frames"]):
        M = np.asarray(fr.get("transform_matrix", ()), dtype=np.float64)
        if "file_path" not in fr or M.shape != (4, 4):
            raise NerfstudioError(f"{source}: frame {k} needs 'file_path' and a 4x4 'transform_matrix'")
        frames.append(NerfstudioFrame(str(fr["file_path"]), M @ OPENCV_TO_OPENGL))
    extra = {k: v for k, v in data.items() if k != "frames"}
    return intr, frames, extra


def read_transforms(path: str | Path) -> tuple[CameraIntrinsics, list[NerfstudioFrame], dict]:
    p = Path(path)
    if not p.is_file():
        raise NerfstudioError(f"transforms file not found: {p}")
    return parse_transforms(p.read_text(), str(p))
