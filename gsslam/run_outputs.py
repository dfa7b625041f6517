"""Run a whole sequence through :class:`gsslam.pipeline.Pipeline` and write the results.

Files in ``out``: ``trajectory.tum`` (every frame that has a pose, dataset timestamps),
``keyframes.tum``, ``config.yaml`` (the resolved config), ``metrics.json`` (ATE when the dataset
has ground truth: Sim(3)-aligned for mono, SE(3) for RGB-D; counts, wall time, FPS, peak RSS,
tracking-loss events) and ``trajectory.png``. They are written in a ``finally`` so that an
interrupted run (Ctrl-C) still leaves the trajectory estimated so far.
"""

from __future__ import annotations

import json
import logging
import resource
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gsslam.config import Config, save_config
from gsslam.datasets.prefetch import FramePrefetcher
from gsslam.pipeline import Pipeline
from gsslam.types import Trajectory

log = logging.getLogger(__name__)

DATASETS_WITH_OPTIONAL_DEPTH = ("tum", "7scenes", "rosbag")  # loaders that take ``with_depth``

ProgressCallback = Callable[[int, int, float], None]  # (frames done, total, frames per second)


@dataclass
class RunResult:
    out: Path
    metrics: dict = field(default_factory=dict)

    def summary_rows(self) -> list[tuple[str, str]]:
        m = self.metrics
        rows = [
            ("frames", f"{m.get('frames_posed', 0)} / {m.get('frames', 0)} posed"),
            ("keyframes", str(m.get("keyframes", 0))),
            ("submaps", f"{m.get('submaps', 0)} in {m.get('chains', 0)} chain(s)"),
            ("tracking events", str(len(m.get("events", [])))),
            ("wall time", f"{m.get('wall_time_s', 0.0):.1f} s ({m.get('fps', 0.0):.1f} FPS)"),
            ("peak RSS", f"{m.get('peak_rss_mb', 0.0):.0f} MB"),
        ]
        mp = m.get("mapper") or {}
        if mp.get("empty"):
            rows.append(("map", "empty: 0 Gaussians (no keyframe had usable depth; docs/pipeline.md)"))
        elif "psnr_keyframes" in mp:
            rows.append(
                (
                    "map",
                    f"{mp['num_gaussians']} Gaussians, {mp['size_mb']:.1f} MB, "
                    f"PSNR {mp['psnr_keyframes']:.1f} dB keyframes / {mp['psnr_other']:.1f} dB held-out "
                    f"({mp['width']}x{mp['height']})",
                )
            )
        lp = m.get("loop_closure") or {}
        if lp.get("enabled"):
            rows.append(
                ("loops", f"{lp['detected']} detected, {lp['accepted']} accepted, {lp['rejected']} rejected")
            )
        for key, label in (
            ("ate", "ATE RMSE (all frames)"),
            ("ate_keyframes", "ATE RMSE (keyframes)"),
            ("ate_before_batch", "ATE RMSE (before batch)"),
        ):
            if m.get(key):
                rows.append(
                    (label, f"{100 * m[key]['rmse_m']:.2f} cm ({m[key]['align']}, {m[key]['pairs']} poses)")
                )
        if m.get("interrupted"):
            rows.append(("interrupted", "yes: outputs hold the poses estimated so far"))
        rows.append(("outputs", str(self.out)))
        return rows


def run_sequence(
    path: str | Path,
    dataset_name: str,
    cfg: Config,
    out: str | Path,
    max_frames: int | None = None,
    progress: bool | ProgressCallback = True,
    **dataset_kwargs: Any,
) -> RunResult:
    """Open the dataset ``dataset_name`` at ``path`` and run :func:`run_dataset` on it.

    ``progress``: a callback ``(done, total, fps)`` called after every frame (the CLI draws a
    progress bar with it); ``True``/``False`` without a callback report nothing (the library never prints).
    """
    from gsslam.datasets.base import open_dataset

    if cfg.mode == "mono" and dataset_name in DATASETS_WITH_OPTIONAL_DEPTH:
        # a monocular run reads no depth, so frames that only lack a depth image are kept
        dataset_kwargs.setdefault("with_depth", False)
    ds = open_dataset(dataset_name, path, **dataset_kwargs)
    callback = progress if callable(progress) else None
    return run_dataset(ds, cfg, Path(out), max_frames=max_frames, progress=callback)


def run_dataset(
    ds, cfg: Config, out: Path, max_frames: int | None = None, progress: ProgressCallback | None = None
) -> RunResult:
    """Run the pipeline over the first ``max_frames`` frames of ``ds``; write the outputs to ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    save_config(cfg, out / "config.yaml")
    n = len(ds) if max_frames is None else min(len(ds), max_frames)
    pipe = Pipeline(cfg, ds.intrinsics)
    result = RunResult(out)
    t0 = time.perf_counter()
    done, interrupted = 0, True
    before_batch: dict[int, np.ndarray] = {}
    try:
        with FramePrefetcher(ds, range(n)) as frames:  # decoding overlaps tracking; same order as ds[i]
            for frame in frames:
                pipe.process(frame)
                done += 1
                if progress is not None:
                    progress(done, n, done / max(time.perf_counter() - t0, 1e-9))
        pipe._close_chain()
        before_batch = pipe.frame_poses()
        pipe.finish()
        interrupted = False
    finally:
        wall = time.perf_counter() - t0
        result.metrics = write_outputs(pipe, ds, out, wall, done, interrupted, before_batch)
    return result


def _trajectory(pipe: Pipeline, poses: dict[int, np.ndarray]) -> Trajectory:
    idx = sorted(i for i in poses if i in pipe.timestamps)
    if not idx:
        return Trajectory(np.zeros(0), np.zeros((0, 4, 4)))
    return Trajectory(np.array([pipe.timestamps[i] for i in idx]), np.stack([poses[i] for i in idx]))


def _ate(gt: Trajectory | None, est: Trajectory, align: str) -> tuple[dict | None, Any]:
    from gsslam.errors import GsslamError
    from gsslam.eval.ate import compute_ate

    if gt is None or len(est) < 3:
        return None, None
    try:
        res, assoc = compute_ate(gt, est, align=align)
    except GsslamError as e:
        log.warning("no ATE: %s", e)
        return None, None
    return {
        "rmse_m": res.stats.rmse,
        "mean_m": res.stats.mean,
        "median_m": res.stats.median,
        "max_m": float(np.max(res.errors)),
        "pairs": len(assoc),
        "align": align,
    }, (res, assoc)


def write_outputs(
    pipe: Pipeline,
    ds,
    out: Path,
    wall: float,
    done: int,
    interrupted: bool,
    before_batch: dict[int, np.ndarray] | None = None,
) -> dict:
    from gsslam.io.trajectory import write_tum

    try:
        poses = pipe.frame_poses()
        kf_poses = pipe.keyframe_poses()
    except Exception as e:  # an interrupted graph may not answer; keep what the files need
        log.warning("could not read poses after interruption: %s", e)
        poses, kf_poses = {}, {}
    traj, kf_traj = _trajectory(pipe, poses), _trajectory(pipe, kf_poses)
    write_tum(traj, out / "trajectory.tum")
    write_tum(kf_traj, out / "keyframes.tum")
    try:  # keyframe images + camera make the run folder self-contained for `gsslam export` / `--viz rerun`
        from gsslam.mapping.render_run import save_intrinsics
        from gsslam.run.keyframes import KEYFRAME_DIR, save_keyframe_images

        save_intrinsics(pipe.intrinsics, out / "intrinsics.yaml")  # also without a map
        kf_stamps = {i: pipe.timestamps[i] for i in kf_poses if i in pipe.timestamps}
        save_keyframe_images(ds, kf_stamps, out / KEYFRAME_DIR)
    except Exception as e:  # images must never lose a run's trajectory and numbers
        log.warning("keyframe images not saved: %s", e)
    align = "sim3" if pipe.monocular else "se3"
    gt = ds.ground_truth()
    ate, pair = _ate(gt, traj, align)
    ate_kf, _ = _ate(gt, kf_traj, align)
    ate_bb, _ = _ate(gt, _trajectory(pipe, before_batch), align) if before_batch else (None, None)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    peak_mb = peak / (1024 * 1024) if sys.platform == "darwin" else peak / 1024
    metrics = {
        "dataset": getattr(ds, "name", type(ds).__name__),
        "mode": pipe.cfg.mode,
        "frames": done,
        "frames_posed": len(traj),
        "keyframes": len(kf_traj),
        "submaps": sum(len(c.encodings) for c in pipe.chains),
        "chains": len(pipe.chains),
        "flow_factors": pipe.n_flow_factors,
        "wall_time_s": wall,
        "fps": done / wall if wall > 0 else 0.0,
        "peak_rss_mb": peak_mb,
        "ate": ate,
        "ate_keyframes": ate_kf,
        "ate_before_batch": ate_bb,
        "events": [{"frame": e.frame_index, "kind": e.kind, "detail": e.detail} for e in pipe.events],
        "interrupted": interrupted,
        "mapper": None,
        "loop_closure": pipe.loop_stage.metrics(),
    }
    if pipe.map_stage is not None:
        try:
            metrics["mapper"] = write_map_outputs(pipe, ds, out, poses, done)
        except Exception as e:  # the map must never lose a run's trajectory and numbers
            log.warning("map outputs failed: %s", e)
            metrics["mapper"] = {"error": str(e)}
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    if pair is not None:
        try:
            from gsslam.viz.plots import plot_trajectory

            res, assoc = pair
            est_xyz = res.alignment.apply_positions(traj.positions[assoc.est_indices])
            plot_trajectory(
                out / "trajectory.png",
                gt.timestamps[assoc.gt_indices],
                gt.positions[assoc.gt_indices],
                est_xyz,
                title=f"ATE {100 * ate['rmse_m']:.2f} cm ({align})",
            )
        except Exception as e:  # a plot must never lose a run's numbers
            log.warning("trajectory plot failed: %s", e)
    return metrics


def write_map_outputs(
    pipe: Pipeline,
    ds,
    out: Path,
    poses: dict[int, np.ndarray],
    done: int,
    max_held_out: int = 40,
    panels: int = 4,
) -> dict:
    """``map.ply``, ``intrinsics.yaml``, ``renders/`` panels; returns the map metrics.

    PSNR / SSIM at the mapper resolution on every mapper keyframe and on up to ``max_held_out``
    non-keyframes spread over the run (held out: never seen by the mapper), with their final poses.
    """
    from gsslam.mapping.render_run import save_intrinsics

    stage = pipe.map_stage
    mapper = stage.mapper
    t0 = time.perf_counter()
    save_intrinsics(pipe.intrinsics, out / "intrinsics.yaml")
    ply_bytes = mapper.save_ply(out / "map.ply")
    mapper.render_keyframe_panels(out / "renders", panels)
    kfs = [i for i in mapper.keyframe_indices if i in poses]
    others = [i for i in sorted(poses) if i < done and i not in set(mapper.keyframe_indices)]
    if len(others) > max_held_out:
        others = [others[int(k)] for k in np.linspace(0, len(others) - 1, max_held_out)]
    frames = [ds[i] for i in sorted(set(kfs) | set(others))]
    ev = mapper.evaluate(frames, poses) if frames else {}
    ev.pop("per_frame_psnr", None)
    refined = stage.refined_keyframe_poses
    if refined and kfs:  # the map after the joint refinement, seen from its own refined keyframe poses
        ev_r = mapper.evaluate([ds[i] for i in kfs], {i: refined[i] for i in kfs if i in refined})
        ev["psnr_keyframes_refined_poses"] = ev_r["psnr_keyframes"]
        ev["ssim_keyframes_refined_poses"] = ev_r["ssim_keyframes"]
        gt = ds.ground_truth()
        align = "sim3" if pipe.monocular else "se3"
        ev["ate_keyframes_refined_poses"], _ = _ate(gt, _trajectory(pipe, refined), align)
    empty = mapper.num_gaussians == 0
    if empty:
        log.warning(
            "the map is empty: no keyframe had depth with confidence >= mapper.min_confidence "
            "(a camera at rest or only rotating observes none); its PSNR is that of a blank render"
        )
    return {
        **stage.metrics(),
        **ev,
        "empty": empty,
        "ply_mb": ply_bytes / 1e6,
        "outputs_seconds": time.perf_counter() - t0,
    }
