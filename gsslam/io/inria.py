"""Model folders of the original 3D Gaussian Splatting code (Kerbl et al. 2023, "INRIA" layout).

``write_inria_model`` writes what that code's viewers and renderers load from a model path::

    point_cloud/iteration_<N>/point_cloud.ply   3DGS PLY with f_rest_* for SH degree d
    cameras.json                                 one entry per camera (see below)
    cfg_args                                     the Namespace(...) line its scripts parse

The loader asserts the number of ``f_rest_*`` properties is ``3 * ((d + 1)**2 - 1)`` for its
``sh_degree`` d, so the PLY carries exactly that many, in the order
``x y z nx ny nz f_dc_0..2 f_rest_0.. opacity scale_0..2 rot_0..3`` (:func:`inria_property_names`).
``f_rest`` is channel-major (all R coefficients, then G, then B); a map with fewer SH bands is padded
with zeros, one with more is truncated. ``cameras.json`` entries hold ``position`` (camera centre in
the world) and ``rotation`` (rows of ``R_world_cam``, OpenCV axes), ``fx``/``fy`` in pixels.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gsslam.errors import GsslamError
from gsslam.io.ply import GaussianPly, write_ply
from gsslam.types import CameraIntrinsics


class InriaError(GsslamError):
    """An INRIA-layout model cannot be written (bad SH degree or inconsistent arrays)."""


@dataclass
class InriaCamera:
    name: str  # image name without folder
    T_world_cam: np.ndarray  # [4, 4]
    intrinsics: CameraIntrinsics


def n_rest(sh_degree: int) -> int:
    """Number of ``f_rest_*`` properties for SH degree ``sh_degree`` (0 -> 0, 3 -> 45)."""
    return 3 * ((sh_degree + 1) ** 2 - 1)


def inria_property_names(sh_degree: int) -> list[str]:
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(n_rest(sh_degree))]
    return names + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]


def with_sh_degree(g: GaussianPly, sh_degree: int) -> GaussianPly:
    """``g`` with ``f_rest`` resized to SH degree ``sh_degree`` (zero padding / truncation per channel)."""
    if not 0 <= sh_degree <= 3:
        raise InriaError(f"SH degree must be 0..3, got {sh_degree}")
    m = g.f_rest.shape[1]
    if m % 3:
        raise InriaError(f"f_rest has {m} columns; expected a multiple of 3 (channel-major SH coefficients)")
    have, want = m // 3, n_rest(sh_degree) // 3
    rest = np.zeros((len(g), 3, want), np.float32)
    k = min(have, want)
    rest[:, :, :k] = g.f_rest.reshape(len(g), 3, have)[:, :, :k]
    return GaussianPly(
        g.means, g.quats_wxyz, g.log_scales, g.opacity_logits, g.f_dc, rest.reshape(len(g), -1)
    )


def camera_entries(cameras: list[InriaCamera]) -> list[dict]:
    out = []
    for k, c in enumerate(cameras):
        T = np.asarray(c.T_world_cam, dtype=np.float64)
        out.append(
            {
                "id": k,
                "img_name": Path(c.name).stem,
                "width": int(c.intrinsics.width),
                "height": int(c.intrinsics.height),
                "position": T[:3, 3].tolist(),
                "rotation": T[:3, :3].tolist(),
                "fy": float(c.intrinsics.fy),
                "fx": float(c.intrinsics.fx),
            }
        )
    return out


def format_cfg_args(sh_degree: int, source_path: str, model_path: str, images: str = "images") -> str:
    return (
        f"Namespace(sh_degree={sh_degree}, source_path={source_path!r}, model_path={model_path!r}, "
        f"images={images!r}, resolution=-1, white_background=False, data_device='cuda', eval=False)"
    )


def write_inria_model(
    folder: str | Path,
    g: GaussianPly,
    cameras: list[InriaCamera],
    sh_degree: int = 3,
    iteration: int = 30000,
    source_path: str = "",
) -> Path:
    """Write the model folder; returns the PLY path."""
    folder = Path(folder)
    ply = folder / "point_cloud" / f"iteration_{int(iteration)}" / "point_cloud.ply"
    write_ply(ply, with_sh_degree(g, sh_degree))
    (folder / "cameras.json").write_text(json.dumps(camera_entries(cameras), indent=1) + "\n")
    (folder / "cfg_args").write_text(format_cfg_args(sh_degree, source_path, str(folder.resolve())))
    return ply


def read_ply_property_names(path: str | Path) -> list[str]:
    """The vertex property names of a PLY header, in file order."""
    raw = Path(path).read_bytes()
    end = raw.find(b"end_header")
    if end < 0:
        raise InriaError(f"{path}: no PLY header")
    names, element = [], None
    for line in raw[:end].decode("ascii", errors="replace").splitlines():
        f = line.split()
        if f[:1] == ["element"]:
            element = f[1]
        elif f[:1] == ["property"] and element == "vertex":
            names.append(f[-1])
    return names
