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

import numpy as np

from gsslam.run.memory import peak_rss_mb, rss_mb

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


def growth_mb_per_100_frames(rss: list[tuple[int, float]], skip: int = 100) -> float | None:
    """Least-squares slope of resident memory against frame index after the first ``skip`` frames."""
    pts = [(f, mb) for f, mb in rss if f > skip]
    if len(pts) < 3:
        return None
    f, mb = (np.array(v, dtype=float) for v in zip(*pts))
    return round(100 * float(np.polyfit(f, mb, 1)[0]), 2)


def run_lengths(
    path: Path | None = None,
    lengths: tuple[int, ...] = (200, 500, 1000),
    mode: str = "rgbd",
    pattern: str = "fbfbfb",
    map_on: bool = True,
    overrides: list[str] | None = None,
    plot: Path | None = None,
) -> dict:
    """Per-stage wall time per frame and memory for growing lengths of one long sequence.

    The sequence is ``path`` (TUM layout) played by ``pattern`` (:mod:`gsslam.datasets.playback`), cut
    at each of ``lengths``; each length is one whole run (defaults: mapper and loops on unless
    ``map_on`` is False) in a fresh process of its own (``multiprocessing`` spawn), so that its memory
    is its own and not what the runs before it left. Stages: ``tracking`` (the frame loop and the
    tail's submap without the two below: flow, keyframes, encoder, graph), ``map`` (the window
    optimisation and seeding after every submap), ``loops``, ``batch`` (the final batch refinement),
    ``final pass`` and ``outputs`` (map metrics, files); all milliseconds per frame of wall time (on a
    shared machine they include waiting for a core, so compare the stages and lengths of one
    invocation, never across machines). Resident memory is sampled every 10 frames; ``plot`` writes it
    as a chart against the frame index; ``peak_rss_mb`` is the process's ``VmHWM`` (peak resident
    memory) after the run and its outputs; ``rss_growth_mb_per_100_frames`` the slope after frame 100.
    ``cpu_s`` is the process's CPU time for the whole run (all threads): the ratio of a map-on to a
    map-off invocation's ``cpu_s`` is the map's cost that the machine's load does not blur.
    """
    import logging
    import multiprocessing

    rows, series = [], {}
    level = logging.getLogger("gsslam").getEffectiveLevel()
    for n in lengths:
        with multiprocessing.get_context("spawn").Pool(1) as pool:  # a fresh process per length
            row, rss = pool.apply(_one_length, (path, n, mode, pattern, map_on, overrides, level))
        rows.append(row)
        series[f"{row['frames']} frames"] = rss
    if plot is not None:
        from gsslam.viz.plots import plot_rss

        plot_rss(plot, series, title=f"resident memory, {mode}, map {'on' if map_on else 'off'}")
    return {"path": str(path or DEFAULT_PATH), "mode": mode, "pattern": pattern, "map": map_on,
            "cpu_cores": os.cpu_count(), "runs": rows, "rss_by_frame": series}  # fmt: skip


def _one_length(
    path: Path | None,
    n: int,
    mode: str,
    pattern: str,
    map_on: bool,
    overrides: list[str] | None,
    log_level: int,
) -> tuple[dict, list[tuple[int, float]]]:
    """One row of :func:`run_lengths` (run in its own process): ``(row, [(frame, resident MB)])``."""
    import logging

    from gsslam.config import load_config
    from gsslam.datasets.base import open_dataset
    from gsslam.run.sequence import run_dataset

    logging.basicConfig(level=log_level, format="%(levelname)s %(name)s: %(message)s")
    base_over = [] if map_on else ["mapper.enabled=false", "loop.enabled=false"]
    ds = open_dataset("playback", path or DEFAULT_PATH, base="tum", pattern=pattern)
    cfg = load_config(None, [*base_over, *(overrides or [])], mode=mode)
    rss: list[tuple[int, float]] = []
    t0, cpu0 = time.perf_counter(), time.process_time()
    load_before = os.getloadavg()[0]

    def frames(done: int, total: int, fps: float) -> None:
        if done % 10 == 0 or done == total:
            rss.append((done, round(rss_mb(), 1)))

    with tempfile.TemporaryDirectory() as tmp:
        m = run_dataset(ds, cfg, Path(tmp), max_frames=n, progress=frames).metrics
    total = time.perf_counter() - t0
    cpu = time.process_time() - cpu0
    st = m.get("stage_seconds", {})
    done = max(1, m["frames"])
    # the run's wall time covers the frame loop, the tail's submap (close_chain), batch and final pass
    loop_s = m["wall_time_s"] - st.get("batch", 0.0) - st.get("final pass", 0.0)
    stages = {
        "tracking": loop_s - st.get("map", 0.0) - st.get("loops", 0.0),
        "map": st.get("map", 0.0),
        "loops": st.get("loops", 0.0),
        "batch": st.get("batch", 0.0),
        "final pass": st.get("final pass", 0.0),
        "outputs": total - m["wall_time_s"],
    }
    ck = m.get("checkpoints") or {}
    row = {
        "frames": m["frames"],
        "keyframes": m["keyframes"],
        "ms_per_frame": {k: round(1e3 * v / done, 1) for k, v in stages.items()},
        "total_s": round(total, 1),
        "cpu_s": round(cpu, 1),
        "final_pass_share": round(stages["final pass"] / total, 3),
        "peak_rss_mb": round(peak_rss_mb()),
        "rss_mb_at_end_of_frames": rss[-1][1] if rss else None,
        "rss_growth_mb_per_100_frames": growth_mb_per_100_frames(rss),
        "last_checkpoint_mb": round(ck.get("bytes_last", 0) / 1e6, 1),
        "last_checkpoint": ck.get("last"),
        "num_gaussians": (m.get("mapper") or {}).get("num_gaussians"),
        "psnr_keyframes_native": (m.get("mapper") or {}).get("psnr_keyframes_native"),
        "ate_rmse_m": m["ate"]["rmse_m"] if m.get("ate") else None,
        "loadavg_1min_before_after": [round(load_before, 1), round(os.getloadavg()[0], 1)],
        "pid": os.getpid(),
    }
    return row, rss
