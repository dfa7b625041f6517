"""``gsslam export``: a run folder as a COLMAP text model, a nerfstudio dataset or an INRIA 3DGS model.

Reads ``keyframes.tum`` (``T_world_cam`` per keyframe), ``intrinsics.yaml``, ``map.ply``,
``config.yaml`` (for the units) and, with ``images=True``, ``keyframes/<timestamp>.jpg`` (written by
the runner). Layouts, all with a ``README.txt`` stating the units:

- ``colmap``: ``sparse/0/{cameras,images,points3D}.txt`` (+ ``images/``), the layout 3DGS trainers
  (INRIA ``train.py -s``, gsplat's ``simple_trainer.py``, nerfstudio's colmap parser) read.
- ``nerfstudio``: ``transforms.json`` (OpenGL camera axes), ``sparse_pc.ply`` (initial points for
  splatfacto, ``ply_file_path``) (+ ``images/``).
- ``inria``: ``point_cloud/iteration_<N>/point_cloud.ply`` with SH degree ``sh_degree``,
  ``cameras.json``, ``cfg_args``, and the COLMAP model + ``images/`` as its source path (SIBR's viewer
  shows the cameras from there).

Points of the COLMAP / nerfstudio exports are the Gaussian means coloured by their DC colour.
"""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import numpy as np
import yaml

from gsslam.errors import GsslamError
from gsslam.run.keyframes import KEYFRAME_DIR, find_keyframe_images, timestamp_name

log = logging.getLogger(__name__)

FORMATS = ("colmap", "nerfstudio", "inria")


class ExportError(GsslamError):
    """A run folder lacks what an export needs, or the export options are inconsistent."""


def run_units(run_dir: str | Path) -> str:
    """``"metres"`` for RGB-D runs, an explicit "arbitrary" for monocular ones (from ``config.yaml``)."""
    cfg = Path(run_dir) / "config.yaml"
    mode = None
    if cfg.is_file():
        mode = (yaml.safe_load(cfg.read_text()) or {}).get("mode")
    if mode == "rgbd":
        return "metres"
    if mode == "mono":
        return "arbitrary (monocular: one unknown global scale, not metres)"
    return "unknown (no mode in config.yaml)"


def _readme(fmt: str, run_dir: Path, units: str, n_images: int, n_points: int) -> str:
    return (
        f"gsslam export --format {fmt} of {run_dir.resolve()}\n"
        f"units: {units}\n"
        f"cameras: {n_images} keyframes, pinhole, undistorted images\n"
        f"points: {n_points} Gaussian means coloured by their DC colour\n"
        "poses: the run's final keyframe poses (keyframes.tum)\n"
    )


def _load_run(run_dir: Path, need_map: bool):
    from gsslam.io.ply import read_ply
    from gsslam.io.trajectory import read_tum
    from gsslam.run.render import load_intrinsics
    from gsslam.run.trajectory_camera import image_poses_file

    for name in ("keyframes.tum", "intrinsics.yaml"):
        if not (run_dir / name).is_file():
            raise ExportError(
                f"{run_dir / name} not found; export needs the folder a `gsslam run` wrote "
                "(runs made before exports existed wrote intrinsics.yaml only with a map: re-run)"
            )
    kf = read_tum(image_poses_file(run_dir, "keyframes"))  # the colour camera's: the images' camera
    intr = load_intrinsics(run_dir / "intrinsics.yaml")
    g = None
    if (run_dir / "map.ply").is_file():
        g = read_ply(run_dir / "map.ply")
    elif need_map:
        raise ExportError(f"{run_dir / 'map.ply'} not found; the INRIA export is the Gaussian map")
    else:
        log.warning("%s has no map.ply: the export has cameras but no points", run_dir)
    return kf, intr, g


def _copy_images(run_dir: Path, stamps: np.ndarray, names: list[str], dst: Path) -> int:
    found = find_keyframe_images(run_dir / KEYFRAME_DIR)
    missing = [timestamp_name(t) for t in stamps if float(t) not in found]
    if missing:
        raise ExportError(
            f"{run_dir / KEYFRAME_DIR} lacks {len(missing)} of {len(stamps)} keyframe images "
            f"(e.g. {missing[0]}.jpg); runs made before keyframe images were saved must be re-run"
        )
    dst.mkdir(parents=True, exist_ok=True)
    for t, name in zip(stamps, names):
        shutil.copyfile(found[float(t)], dst / name)
    return len(names)


def export_run(
    run_dir: str | Path,
    fmt: str,
    out: str | Path | None = None,
    images: bool = False,
    sh_degree: int = 3,
    iteration: int = 30000,
) -> Path:
    """Export ``run_dir`` in format ``fmt`` to ``out`` (default ``run_dir/export_<fmt>``); returns ``out``."""
    from gsslam.io.colmap import ColmapCamera, ColmapImage, ColmapModel, write_colmap_text

    if fmt not in FORMATS:
        raise ExportError(f"unknown export format {fmt!r}; choose one of: {', '.join(FORMATS)}")
    if fmt == "inria" and not 0 <= sh_degree <= 3:
        raise ExportError(f"--sh-degree must be 0..3 (the INRIA code's range), got {sh_degree}")
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise ExportError(f"run folder not found: {run_dir}")
    out = Path(out) if out is not None else run_dir / f"export_{fmt}"
    kf, intr, g = _load_run(run_dir, need_map=fmt == "inria")
    units = run_units(run_dir)
    names = [f"{timestamp_name(t)}.jpg" for t in kf.timestamps]
    xyz = g.means if g is not None else np.zeros((0, 3))
    rgb = g.rgb * 255 if g is not None else np.zeros((0, 3))  # DC colour, 0..255
    out.mkdir(parents=True, exist_ok=True)
    if images:
        _copy_images(run_dir, kf.timestamps, names, out / "images")
    if fmt in ("colmap", "inria"):
        model = ColmapModel(
            [ColmapCamera(1, "PINHOLE", intr.width, intr.height, (intr.fx, intr.fy, intr.cx, intr.cy))],
            [ColmapImage(k + 1, n, 1, T) for k, (n, T) in enumerate(zip(names, kf.poses))],
            xyz,
            rgb,
        )
        write_colmap_text(model, out / "sparse" / "0", comment=f"gsslam export; units: {units}")
    if fmt == "nerfstudio":
        from gsslam.io.nerfstudio import NerfstudioFrame, write_transforms
        from gsslam.io.ply import write_points_ply

        extra = {"gsslam_units": units}
        if g is not None:
            write_points_ply(out / "sparse_pc.ply", xyz, rgb)
            extra["ply_file_path"] = "sparse_pc.ply"
        frames = [NerfstudioFrame(f"images/{n}", T) for n, T in zip(names, kf.poses)]
        write_transforms(out / "transforms.json", intr, frames, extra)
    if fmt == "inria":
        from gsslam.io.inria import InriaCamera, write_inria_model

        cams = [InriaCamera(n, T, intr) for n, T in zip(names, kf.poses)]
        write_inria_model(
            out, g, cams, sh_degree=sh_degree, iteration=iteration, source_path=str(out.resolve())
        )
    (out / "README.txt").write_text(_readme(fmt, run_dir, units, len(names), len(xyz)))
    log.info("exported %s (%d keyframes, %d points, units: %s) to %s", fmt, len(names), len(xyz), units, out)
    return out
