"""A small run folder as `gsslam run` writes it, made without running the pipeline."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import yaml

from gsslam.geometry import make_T, so3_exp
from gsslam.io.ply import GaussianPly, write_ply
from gsslam.io.trajectory import write_tum
from gsslam.run.keyframes import timestamp_name
from gsslam.run.render import save_intrinsics
from gsslam.types import CameraIntrinsics, Trajectory


def make_run(folder: Path, n_kf: int = 5, n_points: int = 200, mode: str = "rgbd", seed: int = 0) -> Path:
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    intr = CameraIntrinsics(535.4, 539.2, 320.1, 247.6, 64, 48)
    stamps = 1311868164.3634 + np.cumsum(rng.uniform(0.03, 0.2, n_kf))
    poses = np.stack([make_T(so3_exp(rng.normal(size=3) * 0.5), rng.normal(size=3)) for _ in range(n_kf)])
    traj = Trajectory(stamps, poses)
    write_tum(traj, folder / "keyframes.tum")
    write_tum(traj, folder / "trajectory.tum")
    save_intrinsics(intr, folder / "intrinsics.yaml")
    (folder / "config.yaml").write_text(yaml.safe_dump({"mode": mode}))
    g = GaussianPly(
        means=rng.normal(size=(n_points, 3)),
        quats_wxyz=np.tile([1.0, 0, 0, 0], (n_points, 1)),
        log_scales=np.full((n_points, 3), -3.0),
        opacity_logits=rng.normal(size=n_points),
        f_dc=rng.normal(size=(n_points, 3)),
    )
    write_ply(folder / "map.ply", g)
    kdir = folder / "keyframes"
    kdir.mkdir(exist_ok=True)
    for t in stamps:
        img = rng.integers(0, 255, (intr.height, intr.width, 3), dtype=np.uint8)
        cv2.imwrite(str(kdir / f"{timestamp_name(t)}.jpg"), img)
    (folder / "metrics.json").write_text(f'{{"frames": {n_kf}}}')
    return folder
