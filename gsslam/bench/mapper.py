"""``gsslam bench mapper``: the Gaussian mapper alone on a TUM RGB-D sequence with ground-truth poses.

Every ``kf_every``-th frame (with a GT pose and depth) becomes a keyframe of one submap; after each one
the mapper runs ``iterations`` steps. Reports, per mapper resolution (``max_side``): keyframe PSNR /
SSIM (at the mapper resolution), held-out PSNR on the frames in between, Gaussian count, map size,
seconds per optimize call and milliseconds per iteration. Default sequence: the bundled 60 frames.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from pathlib import Path

import numpy as np
import torch

from gsslam.config import MapperConfig

_log = logging.getLogger(__name__)

BUNDLED_TUM = Path(__file__).resolve().parents[2] / "data" / "rgbd_dataset_freiburg3_teddy_60"


def run(
    path: Path | None = None,
    max_frames: int = 60,
    kf_every: int = 10,
    iterations: int = 30,
    sides: tuple[int, ...] = (120, 160),
    overrides: dict | None = None,
) -> dict:
    from gsslam.datasets.base import open_dataset
    from gsslam.mapping.mapper import GaussianMapper

    ds = open_dataset("tum", path or BUNDLED_TUM)
    frames = [ds[i] for i in range(min(len(ds), max_frames))]
    frames = [f for f in frames if f.T_world_cam_gt is not None and f.depth is not None]
    kfs = frames[::kf_every]
    held_out = [f for f in frames if f not in kfs][:: max(1, kf_every // 2)]
    poses = {f.index: f.T_world_cam_gt for f in frames}
    results = {
        "sequence": str(path or BUNDLED_TUM),
        "frames": len(frames),
        "keyframes": len(kfs),
        "iterations": iterations,
        "torch_threads": torch.get_num_threads(),
        "by_max_side": {},
    }
    for side in sides:
        torch.manual_seed(0)
        cfg = dataclasses.replace(MapperConfig(), max_side=side, iterations=iterations, **(overrides or {}))
        mapper = GaussianMapper(cfg, ds.intrinsics)
        times, iters_ms = [], []
        t0 = time.perf_counter()
        for f in kfs:
            mapper.add_keyframe(f, f.T_world_cam_gt, submap_id=0)
            st = mapper.optimize()
            times.append(st.get("seconds", 0.0))
            iters_ms.append(st.get("ms_per_iteration", 0.0))
        wall = time.perf_counter() - t0
        ev = mapper.evaluate(kfs + held_out, poses)
        results["by_max_side"][side] = {
            "resolution": f"{ev['width']}x{ev['height']}",
            "psnr_keyframes": round(ev["psnr_keyframes"], 2),
            "ssim_keyframes": round(ev["ssim_keyframes"], 3),
            "psnr_held_out": round(ev["psnr_other"], 2),
            "gaussians": mapper.num_gaussians,
            "size_mb": round(mapper.size_mb, 3),
            "s_per_keyframe": round(float(np.mean(times)), 3),
            "ms_per_iteration": round(float(np.median(iters_ms)), 1),
            "wall_s": round(wall, 1),
        }
        _log.info("max_side %d: %s", side, results["by_max_side"][side])
    return results
