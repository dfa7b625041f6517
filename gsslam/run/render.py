"""``gsslam render``: re-render a saved Gaussian map along a saved trajectory.

A run folder holds ``map.ply`` (3DGS PLY, :mod:`gsslam.io.ply`), ``trajectory.tum`` (``T_world_cam``
per frame) and ``intrinsics.yaml`` (``fx fy cx cy width height`` of the full-resolution camera, written
with :func:`save_intrinsics`). Frames are rendered at the mapper resolution recorded in
``config.yaml`` (``mapper.max_side``; 160 when there is no config), or at any ``size`` (W, H): the
camera's intrinsics are scaled to it (the input's size gives the native-resolution renders).
"""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import torch
import yaml

from gsslam.errors import GsslamError
from gsslam.geometry import invert_T
from gsslam.io.atomic import atomic_path, atomic_write_text
from gsslam.io.trajectory import TrajectoryIOError, read_tum
from gsslam.run.trajectory_camera import image_poses_file
from gsslam.types import CameraIntrinsics

_log = logging.getLogger(__name__)


class RenderRunError(GsslamError):
    """A run folder lacks a file ``gsslam render`` needs, or a file is malformed."""


def save_intrinsics(intrinsics: CameraIntrinsics, path: str | Path) -> None:
    """Write ``intrinsics.yaml`` (pinhole, no distortion) for :func:`render_run`."""
    i = intrinsics
    data = {"fx": i.fx, "fy": i.fy, "cx": i.cx, "cy": i.cy, "width": i.width, "height": i.height}
    atomic_write_text(
        path,
        yaml.safe_dump({k: float(v) if k not in ("width", "height") else int(v) for k, v in data.items()}),
    )


def load_intrinsics(path: str | Path) -> CameraIntrinsics:
    p = Path(path)
    if not p.is_file():
        raise RenderRunError(f"{p} not found; the run must save its camera with save_intrinsics()")
    try:
        d = yaml.safe_load(p.read_text(encoding="utf-8")) or {}
        return CameraIntrinsics(
            float(d["fx"]), float(d["fy"]), float(d["cx"]), float(d["cy"]), int(d["width"]), int(d["height"])
        )
    except KeyError as e:
        raise RenderRunError(f"{p}: missing key {e}; need fx, fy, cx, cy, width, height") from None
    except (yaml.YAMLError, UnicodeDecodeError, TypeError, ValueError, AttributeError, GsslamError):
        raise RenderRunError(
            f"{p} is not a valid intrinsics file (a mapping of fx, fy, cx, cy, width, height); "
            "rerun gsslam run to rewrite it"
        ) from None


def _read_tum(path: Path) -> tuple[np.ndarray, np.ndarray]:  # -> timestamps [N], T_world_cam [N, 4, 4]
    if not path.is_file():
        raise RenderRunError(f"trajectory not found: {path}")
    try:
        traj = read_tum(path)
    except TrajectoryIOError as e:
        raise RenderRunError(str(e)) from None
    return traj.timestamps, traj.poses


def parse_size(text: str) -> tuple[int, int]:
    """``"640x480"`` -> (640, 480)."""
    w, sep, h = text.lower().partition("x")
    try:
        size = (int(w), int(h))
    except ValueError:
        size = (0, 0)
    if not sep or min(size) <= 0:
        raise RenderRunError(f"size must be WxH with positive integers, e.g. 640x480; got {text!r}")
    return size


def scaled_to(intr: CameraIntrinsics, width: int, height: int) -> CameraIntrinsics:
    """The camera ``intr`` resized to ``width`` x ``height`` pixels (pixel-centre convention)."""
    sx, sy = width / intr.width, height / intr.height
    return CameraIntrinsics(
        intr.fx * sx, intr.fy * sy, (intr.cx + 0.5) * sx - 0.5, (intr.cy + 0.5) * sy - 0.5, width, height
    )


def render_run(
    run_dir: str | Path, out_dir: str | Path, every: int = 10, size: tuple[int, int] | None = None
) -> int:
    """Render every ``every``-th pose of ``run_dir/trajectory.tum`` into ``out_dir``; returns the count.

    Each PNG is ``render | depth`` (turbo colour map, black where the map is empty), at the mapper
    resolution or at ``size`` = (width, height).
    """
    from gsslam.io.ply import read_ply
    from gsslam.mapping.gaussians import SH_C0
    from gsslam.mapping.outputs import depth_colormap
    from gsslam.mapping.rasterize import render

    run_dir, out_dir = Path(run_dir), Path(out_dir)
    if every < 1:
        raise RenderRunError(f"--every must be >= 1, got {every}")
    g = read_ply(run_dir / "map.ply")
    intr = load_intrinsics(run_dir / "intrinsics.yaml")
    ts, poses = _read_tum(image_poses_file(run_dir, "trajectory"))  # the colour camera's: the map's
    max_side = 160
    cfg_path = run_dir / "config.yaml"
    if cfg_path.is_file():
        from gsslam.config import read_config_file

        value = (read_config_file(cfg_path).get("mapper") or {}).get("max_side", 160)
        if isinstance(value, bool) or not isinstance(value, int) or value < 16:
            raise RenderRunError(
                f"{cfg_path}: mapper.max_side must be an integer >= 16, got {value!r}; fix or delete the file"
            )
        max_side = value
    if size is None:
        intr = intr.scaled(min(1.0, max_side / max(intr.width, intr.height)))
    else:
        intr = scaled_to(intr, *size)
    K = torch.tensor(intr.K, dtype=torch.float32)
    means = torch.as_tensor(g.means)
    quats = torch.as_tensor(g.quats_wxyz)
    scales = torch.exp(torch.as_tensor(g.log_scales))
    opac = torch.sigmoid(torch.as_tensor(g.opacity_logits))
    rgb = (0.5 + SH_C0 * torch.as_tensor(g.f_dc)).clamp(0, 1)
    out_dir.mkdir(parents=True, exist_ok=True)
    count = 0
    for i in range(0, len(poses), every):
        T_cw = torch.as_tensor(invert_T(poses[i]), dtype=torch.float32)
        with torch.no_grad():
            out = render(means, quats, scales, opac, rgb, T_cw, K, intr.width, intr.height)
        color = (out.color.clamp(0, 1).numpy() * 255).astype(np.uint8)[..., ::-1]
        dc = depth_colormap(out.depth.numpy(), out.alpha.numpy() > 0.5)
        with atomic_path(out_dir / f"render_{i:06d}_{ts[i]:.6f}.png") as tmp:
            cv2.imwrite(str(tmp), np.concatenate([color, dc], axis=1))
        count += 1
    _log.info("rendered %d of %d poses (%dx%d) to %s", count, len(poses), intr.width, intr.height, out_dir)
    return count
