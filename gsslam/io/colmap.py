"""COLMAP text models: ``cameras.txt``, ``images.txt``, ``points3D.txt`` (COLMAP's documented format).

- ``cameras.txt``: ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]``; we write ``PINHOLE`` (``fx fy cx cy``).
- ``images.txt``: two lines per image. The first is ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME``:
  the **world-to-camera** pose ``T_cam_world`` as a (w, x, y, z) quaternion and a translation. The
  second lists ``X Y POINT3D_ID`` observations; we write it empty (no 2D-3D tracks).
- ``points3D.txt``: ``POINT3D_ID X Y Z R G B ERROR TRACK[]`` with 8-bit colour; tracks are empty.

Readers and writers here work on :class:`ColmapModel`, which stores poses as ``T_world_cam``
(camera-to-world, like the rest of gsslam); the conversion happens at the file boundary. Numbers are
written with ``repr`` so that they read back bit-identical. Lines starting with ``#`` are comments.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gsslam.errors import GsslamError
from gsslam.geometry import invert_T, quat_to_rot, rot_to_quat

# parameter counts of the COLMAP camera models we can read back (COLMAP's documented list)
CAMERA_MODEL_PARAMS = {
    "SIMPLE_PINHOLE": 3,
    "PINHOLE": 4,
    "SIMPLE_RADIAL": 4,
    "RADIAL": 5,
    "OPENCV": 8,
    "OPENCV_FISHEYE": 8,
    "FULL_OPENCV": 12,
}


class ColmapError(GsslamError):
    """A COLMAP text model is missing, malformed, or cannot be written."""


@dataclass
class ColmapCamera:
    camera_id: int
    model: str
    width: int
    height: int
    params: tuple[float, ...]  # PINHOLE: fx fy cx cy


@dataclass
class ColmapImage:
    image_id: int
    name: str
    camera_id: int
    T_world_cam: np.ndarray  # [4, 4] camera-to-world


@dataclass
class ColmapModel:
    cameras: list[ColmapCamera]
    images: list[ColmapImage]
    points_xyz: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # [N, 3]
    points_rgb: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.uint8))  # [N, 3] uint8


def _f(v: float) -> str:
    return repr(float(v))


def pose_to_colmap(T_world_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # -> q_wxyz [4], t [3]
    """COLMAP's ``(QW QX QY QZ), (TX TY TZ)`` of ``T_cam_world = inverse(T_world_cam)``."""
    T_cw = invert_T(np.asarray(T_world_cam, dtype=np.float64))
    q = rot_to_quat(T_cw[:3, :3])  # (x, y, z, w)
    return np.array([q[3], q[0], q[1], q[2]]), T_cw[:3, 3].copy()


def pose_from_colmap(q_wxyz: np.ndarray, t: np.ndarray) -> np.ndarray:  # -> T_world_cam [4, 4]
    q = np.asarray(q_wxyz, dtype=np.float64)
    T_cw = np.eye(4)
    T_cw[:3, :3] = quat_to_rot(np.array([q[1], q[2], q[3], q[0]]))
    T_cw[:3, 3] = t
    return invert_T(T_cw)


def format_cameras(cameras: list[ColmapCamera], comment: str = "") -> str:
    lines = [
        "# Camera list with one line of data per camera:",
        "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
    ]
    lines += [f"# {c}" for c in comment.splitlines()]
    lines.append(f"# Number of cameras: {len(cameras)}")
    for c in cameras:
        if c.model not in CAMERA_MODEL_PARAMS or len(c.params) != CAMERA_MODEL_PARAMS[c.model]:
            raise ColmapError(
                f"camera {c.camera_id}: model {c.model} with {len(c.params)} params is not valid"
            )
        lines.append(f"{c.camera_id} {c.model} {c.width} {c.height} " + " ".join(_f(p) for p in c.params))
    return "\n".join(lines) + "\n"


def format_images(images: list[ColmapImage], comment: str = "") -> str:
    lines = [
        "# Image list with two lines of data per image:",
        "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
        "#   POINTS2D[] as (X, Y, POINT3D_ID)",
    ]
    lines += [f"# {c}" for c in comment.splitlines()]
    lines.append(f"# Number of images: {len(images)}, mean observations per image: 0")
    for im in images:
        if not im.name or any(ch.isspace() for ch in im.name):
            raise ColmapError(f"image {im.image_id}: name {im.name!r} must be non-empty without spaces")
        q, t = pose_to_colmap(im.T_world_cam)
        vals = " ".join(_f(v) for v in (*q, *t))
        lines.append(f"{im.image_id} {vals} {im.camera_id} {im.name}")
        lines.append("")  # no 2D observations
    return "\n".join(lines) + "\n"


def format_points(xyz: np.ndarray, rgb: np.ndarray, comment: str = "") -> str:
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    rgb = np.asarray(rgb).reshape(-1, 3)
    if len(rgb) != len(xyz):
        raise ColmapError(f"{len(xyz)} points but {len(rgb)} colours")
    rgb = np.clip(np.round(rgb), 0, 255).astype(np.int64)
    lines = [
        "# 3D point list with one line of data per point:",
        "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)",
    ]
    lines += [f"# {c}" for c in comment.splitlines()]
    lines.append(f"# Number of points: {len(xyz)}, mean track length: 0")
    for i, (p, c) in enumerate(zip(xyz, rgb), start=1):
        lines.append(f"{i} {_f(p[0])} {_f(p[1])} {_f(p[2])} {c[0]} {c[1]} {c[2]} 0")
    return "\n".join(lines) + "\n"


def write_colmap_text(model: ColmapModel, folder: str | Path, comment: str = "") -> None:
    """Write ``cameras.txt``, ``images.txt``, ``points3D.txt`` into ``folder`` (created).

    ``comment`` (e.g. the units) is added as ``#`` lines to each file's header.
    """
    folder = Path(folder)
    ids = {c.camera_id for c in model.cameras}
    for im in model.images:
        if im.camera_id not in ids:
            raise ColmapError(f"image {im.name} refers to camera {im.camera_id}, which is not in the model")
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "cameras.txt").write_text(format_cameras(model.cameras, comment))
    (folder / "images.txt").write_text(format_images(model.images, comment))
    (folder / "points3D.txt").write_text(format_points(model.points_xyz, model.points_rgb, comment))


def _rows(path: Path) -> list[tuple[int, str]]:
    if not path.is_file():
        raise ColmapError(f"COLMAP file not found: {path}")
    return [(n, line) for n, line in enumerate(path.read_text().splitlines(), 1)]


def _parse(path: Path, n: int, fields: list[str], types: list[type]) -> list:
    try:
        return [t(f) for t, f in zip(types, fields)]
    except ValueError:
        raise ColmapError(f"{path}:{n}: not a number in {' '.join(fields)!r}") from None


def read_colmap_text(folder: str | Path) -> ColmapModel:
    """Read a COLMAP text model (the inverse of :func:`write_colmap_text`; any tracks are ignored)."""
    folder = Path(folder)
    cameras = []
    path = folder / "cameras.txt"
    for n, line in _rows(path):
        f = line.split()
        if not f or f[0].startswith("#"):
            continue
        if len(f) < 4 or f[1] not in CAMERA_MODEL_PARAMS or len(f) != 4 + CAMERA_MODEL_PARAMS[f[1]]:
            raise ColmapError(f"{path}:{n}: expected 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]', got {line!r}")
        cid, w, h = _parse(path, n, [f[0], f[2], f[3]], [int, int, int])
        cameras.append(ColmapCamera(cid, f[1], w, h, tuple(_parse(path, n, f[4:], [float] * len(f[4:])))))
    images = []
    path = folder / "images.txt"
    rows = [(n, line) for n, line in _rows(path) if not line.lstrip().startswith("#")]
    k = 0
    while k < len(rows):
        n, line = rows[k]
        f = line.split()
        if not f:  # blank lines between entries are tolerated
            k += 1
            continue
        if len(f) != 10:
            raise ColmapError(
                f"{path}:{n}: expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME', got {line!r}"
            )
        v = _parse(path, n, f[:9], [int] + [float] * 7 + [int])
        images.append(ColmapImage(v[0], f[9], v[8], pose_from_colmap(np.array(v[1:5]), np.array(v[5:8]))))
        k += 2  # the POINTS2D line follows (possibly empty)
    xyz, rgb = [], []
    path = folder / "points3D.txt"
    for n, line in _rows(path):
        f = line.split()
        if not f or f[0].startswith("#"):
            continue
        if len(f) < 8 or (len(f) - 8) % 2:
            raise ColmapError(f"{path}:{n}: expected 'POINT3D_ID X Y Z R G B ERROR TRACK[]', got {line!r}")
        v = _parse(path, n, f[1:7], [float] * 3 + [int] * 3)
        xyz.append(v[:3])
        rgb.append(v[3:6])
    return ColmapModel(
        cameras,
        images,
        np.array(xyz, dtype=np.float64).reshape(-1, 3),
        np.array(rgb, dtype=np.uint8).reshape(-1, 3),
    )
