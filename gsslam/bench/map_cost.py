"""``gsslam bench map-cost``: what the map costs a whole run, and the native PSNR it buys, by resolution.

One run with the mapper off (loops as configured), then one whole run per mapper resolution
(``mapper.max_side`` in ``sides``; ``"full"`` means the input's own size) on the same sequence, in one
process. Reported per run: CPU seconds of the process (all threads, the outputs included: the map's
evaluation is part of a mapped run), the ratio to the map-off run's CPU seconds (the issue's
"map-on / map-off" measure; on a shared machine ratios of one invocation mean more than seconds),
wall seconds, frames per second of wall time, the final pass's share of the wall time, map steps,
keyframe and held-out PSNR at the mapper's resolution and at the input's (``*_native``), Gaussians
and peak resident memory.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

DEFAULT_PATH = Path(__file__).resolve().parents[2] / "data" / "rgbd_dataset_freiburg3_teddy_60"


def _one(ds, cfg, max_frames: int | None) -> tuple[dict, float, float]:
    from gsslam.run.sequence import run_dataset

    cpu0, t0 = time.process_time(), time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        m = run_dataset(ds, cfg, Path(tmp), max_frames=max_frames).metrics
    return m, time.process_time() - cpu0, time.perf_counter() - t0


def _r(x, nd: int = 2):
    return None if x is None else round(float(x), nd)


def run(
    path: Path | None = None,
    dataset: str = "tum",
    mode: str = "rgbd",
    sides: tuple[int | str, ...] = (160, 240, 320),
    max_frames: int | None = None,
    overrides: list[str] | None = None,
) -> dict:
    from gsslam.config import load_config
    from gsslam.datasets.base import open_dataset

    ds = open_dataset(dataset, path or DEFAULT_PATH)
    over = list(overrides or [])
    off_cfg = load_config(None, ["mapper.enabled=false", *over], mode=mode)
    m_off, cpu_off, wall_off = _one(ds, off_cfg, max_frames)
    rows = [{"max_side": "off", "cpu_s": _r(cpu_off, 1), "ratio_cpu": 1.0, "wall_s": _r(wall_off, 1),
             "fps": _r(m_off["fps"]), "ate_rmse_m": _r((m_off.get("ate") or {}).get("rmse_m"), 4),
             "peak_rss_mb": round(m_off["peak_rss_mb"])}]  # fmt: skip
    native_side = max(ds.intrinsics.width, ds.intrinsics.height)
    for side in sides:
        side = native_side if side == "full" else int(side)
        cfg = load_config(None, [*over, f"mapper.max_side={side}"], mode=mode)
        m, cpu, wall = _one(ds, cfg, max_frames)
        mp = m.get("mapper") or {}
        st = m.get("stage_seconds", {})
        rows.append(
            {
                "max_side": side,
                "cpu_s": _r(cpu, 1),
                "ratio_cpu": _r(cpu / max(cpu_off, 1e-9)),
                "wall_s": _r(wall, 1),
                "fps": _r(m["frames"] / wall),
                "final_pass_share": _r(st.get("final pass", 0.0) / wall, 3),
                "map_steps": (mp.get("iterations") or 0) + (mp.get("final_iterations") or 0),
                "psnr_keyframes": _r(mp.get("psnr_keyframes")),
                "psnr_keyframes_native": _r(mp.get("psnr_keyframes_native")),
                "psnr_other": _r(mp.get("psnr_other")),
                "psnr_other_native": _r(mp.get("psnr_other_native")),
                "num_gaussians": mp.get("num_gaussians"),
                "ate_rmse_m": _r((m.get("ate") or {}).get("rmse_m"), 4),
                "peak_rss_mb": round(m["peak_rss_mb"]),
            }
        )
    return {
        "path": str(path or DEFAULT_PATH),
        "dataset": dataset,
        "mode": mode,
        "frames": m_off["frames"],
        "overrides": over,
        "cpu_cores": os.cpu_count(),
        "loadavg_1min_end": round(os.getloadavg()[0], 1),
        "runs": rows,
    }
