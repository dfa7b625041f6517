"""``gsslam bench pipeline``: tracking + graph frames per second, without the mapper.

Runs the whole pipeline (flow tracking, keyframes, submap encoding, flow factors, iSAM2 updates,
final batch refinement) over the first ``max_frames`` frames with ``mapper.enabled=false`` and
``loop.enabled=false``. Frames are read ahead by a background thread (:mod:`gsslam.datasets.prefetch`)
unless ``prefetch=False``. Reported: wall time and FPS, the CPU time of the process
(``time.process_time``: all threads; on a shared machine wall time includes waiting for a core),
the time the pipeline waited for frames, the 1-minute load average before and
after (how busy the machine was) and the ATE when the dataset has ground truth.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

DEFAULT_PATH = Path(__file__).resolve().parents[2] / "data" / "rgbd_dataset_freiburg3_teddy_60"


class _TimedDataset:
    """Wraps a dataset and measures the time the caller spends getting frames."""

    def __init__(self, ds) -> None:
        self.ds = ds
        self.name = ds.name
        self.intrinsics = ds.intrinsics
        self.has_depth = ds.has_depth
        self.load_s = 0.0

    def __len__(self) -> int:
        return len(self.ds)

    def __getitem__(self, i):
        t = time.perf_counter()
        f = self.ds[i]
        self.load_s += time.perf_counter() - t
        return f

    def timestamps(self):
        return self.ds.timestamps()

    def ground_truth(self):
        return self.ds.ground_truth()


def run(
    path: Path | None = None,
    max_frames: int = 60,
    mode: str = "rgbd",
    dataset: str = "tum",
    prefetch: bool = True,
    overrides: list[str] | None = None,
) -> dict:
    from gsslam.config import load_config
    from gsslam.datasets.base import open_dataset
    from gsslam.datasets.prefetch import PrefetchedDataset
    from gsslam.run.sequence import run_dataset

    base = open_dataset(dataset, path or DEFAULT_PATH)
    inner = PrefetchedDataset(base, stop=max_frames) if prefetch else base
    ds = _TimedDataset(inner)
    cfg = load_config(None, ["mapper.enabled=false", "loop.enabled=false", *(overrides or [])], mode=mode)
    load_before = os.getloadavg()[0]
    cpu0 = time.process_time()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            result = run_dataset(ds, cfg, Path(tmp), max_frames=max_frames)
    finally:
        if prefetch:
            inner.close()
    cpu = time.process_time() - cpu0  # includes writing outputs (trajectory plot)
    m = result.metrics
    wall = m["wall_time_s"]
    compute = wall - ds.load_s
    return {
        "path": str(path or DEFAULT_PATH),
        "mode": mode,
        "resolution": f"{ds.intrinsics.width}x{ds.intrinsics.height}",
        "flow": f"{cfg.flow.method} {cfg.flow.dis_preset} max_side={cfg.flow.max_side}",
        "prefetch": prefetch,
        "frames": m["frames"],
        "keyframes": m["keyframes"],
        "submaps": m["submaps"],
        "wall_s": round(wall, 3),
        "fps_total": round(m["fps"], 2),
        "cpu_s_incl_outputs": round(cpu, 3),
        "frame_wait_s": round(ds.load_s, 3),
        "fps_without_frame_wait": round(m["frames"] / compute, 2) if compute > 0 else None,
        "loadavg_1min_before_after": [round(load_before, 2), round(os.getloadavg()[0], 2)],
        "cpu_cores": os.cpu_count(),
        "ate_rmse_m": m["ate"]["rmse_m"] if m.get("ate") else None,
    }
