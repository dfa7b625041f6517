"""``gsslam bench pipeline``: tracking + graph frames per second, without the mapper.

Runs the whole pipeline (flow tracking, keyframes, submap encoding, flow factors, iSAM2 updates,
final batch refinement) over the first ``max_frames`` frames with ``mapper.enabled=false`` and
``loop.enabled=false``, and reports the time split: frame loading vs everything else.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

DEFAULT_PATH = Path(__file__).resolve().parents[2] / "data" / "rgbd_dataset_freiburg3_teddy_60"


class _TimedDataset:
    """Wraps a dataset and measures the time spent reading frames."""

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


def run(path: Path | None = None, max_frames: int = 60, mode: str = "rgbd", dataset: str = "tum") -> dict:
    from gsslam.config import load_config
    from gsslam.datasets.base import open_dataset
    from gsslam.run_outputs import run_dataset

    ds = _TimedDataset(open_dataset(dataset, path or DEFAULT_PATH))
    cfg = load_config(None, ["mapper.enabled=false", "loop.enabled=false"], mode=mode)
    with tempfile.TemporaryDirectory() as tmp:
        result = run_dataset(ds, cfg, Path(tmp), max_frames=max_frames)
    m = result.metrics
    wall = m["wall_time_s"]
    compute = wall - ds.load_s
    return {
        "path": str(path or DEFAULT_PATH),
        "mode": mode,
        "resolution": f"{ds.intrinsics.width}x{ds.intrinsics.height}",
        "frames": m["frames"],
        "keyframes": m["keyframes"],
        "submaps": m["submaps"],
        "wall_s": round(wall, 3),
        "fps_total": round(m["fps"], 2),
        "frame_loading_s": round(ds.load_s, 3),
        "fps_without_loading": round(m["frames"] / compute, 2) if compute > 0 else None,
        "ate_rmse_m": m["ate"]["rmse_m"] if m.get("ate") else None,
    }
