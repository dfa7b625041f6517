"""The files of a run: trajectories, metrics (ATE, counts, timings, events) and the map's outputs.

``trajectory.tum`` (every frame that has a pose, dataset timestamps), ``keyframes.tum``,
``metrics.json``, ``trajectory.png``; with the map: ``map.ply``, ``intrinsics.yaml`` and ``renders/``.

Every file is written atomically (:mod:`gsslam.io.atomic`). ``metrics.json`` carries ``"status"``:
``"running"`` (written when the run starts), ``"partial"`` (trajectories and their numbers are
written; the slow map outputs are not yet) and ``"complete"``. So a second Ctrl-C while the map is
being written, or a kill, never loses the files already complete.

ATE is one number only when every chain is in one world frame: a single chain, or later chains
re-localized against an earlier one (RGB-D, ``Chain.in_world``). Otherwise ``"ate"`` is ``null`` and
``"ate_per_chain"`` gives one ATE per chain (each aligned on its own): never a silently mixed number.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path
from typing import Any

import numpy as np

from gsslam.errors import GsslamError
from gsslam.eval.ate import compute_ate
from gsslam.io.atomic import atomic_write_text
from gsslam.io.trajectory import write_tum
from gsslam.run.memory import peak_rss_mb
from gsslam.run.trajectory_camera import COLOUR, COLOUR_SUFFIX, TrajectoryCamera
from gsslam.slam.pipeline import Pipeline
from gsslam.types import StageProgress, Trajectory

log = logging.getLogger(__name__)


def trajectory_of(pipe: Pipeline, poses: dict[int, np.ndarray]) -> Trajectory:
    """The frames of ``poses`` that have a timestamp, in index order, as a trajectory."""
    idx = sorted(i for i in poses if i in pipe.timestamps)
    if not idx:
        return Trajectory(np.zeros(0), np.zeros((0, 4, 4)))
    return Trajectory(np.array([pipe.timestamps[i] for i in idx]), np.stack([poses[i] for i in idx]))


def ate_metrics(gt: Trajectory | None, est: Trajectory, align: str) -> tuple[dict | None, Any]:
    """ATE of ``est`` against ``gt`` as the metrics dict (and the result and association), or ``None``."""
    if gt is None or len(est) < 3:
        return None, None
    try:
        res, assoc = compute_ate(gt, est, align=align)
    except (GsslamError, np.linalg.LinAlgError, ValueError) as e:  # numbers must never lose the files
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


def write_metrics(out: Path, metrics: dict) -> None:
    """``metrics.json``, atomically."""
    atomic_write_text(out / "metrics.json", json.dumps(metrics, indent=2, default=_json_default))


def _json_default(v: Any) -> Any:
    if isinstance(v, np.generic):
        return v.item()
    raise TypeError(f"{type(v).__name__} is not JSON serializable")


def one_world(pipe: Pipeline) -> bool:
    """True when every chain's placement in the world is verified (one chain, or re-localized ones)."""
    return all(c.in_world for c in pipe.chains)


def ate_per_chain(pipe: Pipeline, gt: Trajectory | None, poses: dict[int, np.ndarray], align: str) -> list:
    """One ATE record per chain (``None`` where a chain has fewer than 3 poses with ground truth)."""
    chain_of = pipe.frame_chains()
    out = []
    for cid in range(len(pipe.chains)):
        mine = {i: T for i, T in poses.items() if chain_of.get(i) == cid}
        ate, _ = ate_metrics(gt, trajectory_of(pipe, mine), align)
        out.append({"chain": cid, "frames_posed": len(mine), "ate": ate})
    return out


def write_outputs(
    pipe: Pipeline,
    ds,
    out: Path,
    wall: float,
    done: int,
    interrupted: bool,
    before_batch: dict[int, np.ndarray] | None = None,
    provenance: dict | None = None,
    progress: StageProgress | None = None,
    extra: dict | None = None,
    camera: TrajectoryCamera = COLOUR,
) -> dict:
    """Write the trajectories, ``metrics.json`` (partial), the plot, the map outputs, then ``metrics.json``
    complete; returns the metrics.

    ``peak_rss_mb`` is the peak resident size at the very end (after the map's evaluation);
    ``peak_rss_mb_before_outputs`` the same before the outputs were written: the run's own peak where
    :func:`gsslam.run.memory.reset_peak_rss` could reset it when the run started (Linux), else the
    process's (``peak_rss_scope`` in ``extra`` says which).

    ``camera``: the camera ``trajectory.tum`` / ``keyframes.tum`` and every ATE are of
    (:mod:`gsslam.run.trajectory_camera`); when it is not the colour camera, the colour camera's poses are
    written beside them (``*_colour.tum``). The map's outputs always use the colour camera's poses.
    """
    try:
        poses = pipe.frame_poses()
        kf_poses = pipe.keyframe_poses()
    except Exception as e:  # an interrupted graph may not answer; keep what the files need
        log.warning("could not read poses after interruption: %s", e)
        poses, kf_poses = {}, {}
    if not camera.is_colour:
        write_tum(trajectory_of(pipe, poses), out / f"trajectory{COLOUR_SUFFIX}.tum")
        write_tum(trajectory_of(pipe, kf_poses), out / f"keyframes{COLOUR_SUFFIX}.tum")
    traj = trajectory_of(pipe, camera.apply(poses, pipe.timestamps))
    kf_traj = trajectory_of(pipe, camera.apply(kf_poses, pipe.timestamps, velocity_from=poses))
    write_tum(traj, out / "trajectory.tum")
    write_tum(kf_traj, out / "keyframes.tum")
    try:  # keyframe images + camera make the run folder self-contained for `gsslam export` / `--viz rerun`
        from gsslam.run.keyframes import KEYFRAME_DIR, save_keyframe_images
        from gsslam.run.render import save_intrinsics

        save_intrinsics(pipe.intrinsics, out / "intrinsics.yaml")  # also without a map
        kf_stamps = {i: pipe.timestamps[i] for i in kf_poses if i in pipe.timestamps}
        save_keyframe_images(ds, kf_stamps, out / KEYFRAME_DIR)
    except Exception as e:  # images must never lose a run's trajectory and numbers
        log.warning("keyframe images not saved: %s", e)
    align = "sim3" if pipe.monocular else "se3"
    gt = ds.ground_truth()
    joined = one_world(pipe)  # chains not in one world frame: no single ATE
    ate, pair = ate_metrics(gt, traj, align) if joined else (None, None)
    ate_kf, _ = ate_metrics(gt, kf_traj, align) if joined else (None, None)
    ate_bb, _ = (
        ate_metrics(gt, trajectory_of(pipe, camera.apply(before_batch, pipe.timestamps)), align)
        if before_batch and joined
        else (None, None)
    )
    online = getattr(pipe, "online_poses", None)  # the pose process() returned for each frame
    ate_on, _ = (
        ate_metrics(gt, trajectory_of(pipe, camera.apply(online, pipe.timestamps)), align)
        if online and joined
        else (None, None)
    )
    peak_mb = peak_rss_mb()
    metrics = {
        "dataset": getattr(ds, "name", type(ds).__name__),
        "mode": pipe.cfg.mode,
        "frames": done,
        "frames_posed": len(traj),
        "keyframes": len(kf_traj),
        "submaps": sum(len(c.encodings) for c in pipe.chains),
        "chains": len(pipe.chains),
        "chains_in_world": sum(c.in_world for c in pipe.chains),
        "flow_factors": pipe.n_flow_factors,
        "frames_icp_tracked": getattr(pipe, "n_icp_tracked", 0),  # RGB-D: ICP after a refused PnP
        "wall_time_s": wall,
        "fps": done / wall if wall > 0 else 0.0,
        "stage_seconds": dict(pipe.stage_seconds),
        "peak_rss_mb": peak_mb,
        "peak_rss_mb_before_outputs": peak_mb,
        "ate": ate,
        "ate_keyframes": ate_kf,
        "ate_before_batch": ate_bb,
        "ate_online": ate_on,
        "frames_posed_online": len(online or {}),
        "ate_per_chain": None if joined else ate_per_chain(pipe, gt, camera.apply(poses, pipe.timestamps),
                                                           align),
        "trajectory_camera": camera.record(),
        "events": [{"frame": e.frame_index, "kind": e.kind, "detail": e.detail} for e in pipe.events],
        "interrupted": interrupted,
        "mapper": None,
        "loop_closure": pipe.loop_stage.metrics(),
        "provenance": dict(provenance or {}),
        **(extra or {}),
    }
    metrics = {"status": "partial", **metrics}
    if pipe.map_stage is not None:
        metrics["mapper"] = {"status": "pending: the map outputs are written after this file"}
    write_metrics(out, metrics)  # the trajectory's numbers are safe before the slow map outputs
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
    if pipe.map_stage is not None:
        try:
            metrics["mapper"] = write_map_outputs(
                pipe, ds, out, poses, done, progress=progress, camera=camera
            )
        except Exception as e:  # the map must never lose a run's trajectory and numbers
            log.warning("map outputs failed: %s", e)
            metrics["mapper"] = {"error": str(e)}
        from gsslam.mapping.rasterize import backends_used

        metrics["provenance"]["rasterizer"] = backends_used()
    else:
        metrics["provenance"]["rasterizer"] = None
    metrics["status"] = "complete"
    metrics["peak_rss_mb"] = peak_rss_mb()  # after the map's evaluation: the true peak of the run
    write_metrics(out, metrics)
    return metrics


def write_map_outputs(
    pipe: Pipeline,
    ds,
    out: Path,
    poses: dict[int, np.ndarray],
    done: int,
    max_held_out: int = 40,
    panels: int = 4,
    progress: StageProgress | None = None,
    panels_worst: int = 2,
    camera: TrajectoryCamera = COLOUR,
) -> dict:
    """``map.ply``, ``intrinsics.yaml``, ``renders/`` panels; returns the map metrics.

    PSNR / SSIM on every mapper keyframe and on up to ``max_held_out`` non-keyframes spread over the
    run (held out: never seen by the mapper), with their final poses, at the mapper resolution; at the
    input's (``*_native``, renders ~16x the pixels) on a fixed sample: at most
    ``run.native_eval_keyframes`` keyframes and ``run.native_eval_held_out`` of those held-out frames,
    evenly spaced (:func:`gsslam.mapping.outputs.evenly_spaced`). The metrics name the sample
    (``native_frames``), its size (``n_keyframes_native``, ``n_other_native``) and each frame's native
    PSNR (``per_frame_psnr_native``): the native scores are the means over exactly those frames.
    Frames are read one at a time, so memory does not grow with the run.
    ``renders/worst_<frame>_<psnr>dB.png``: the ``panels_worst`` keyframes whose renders score lowest,
    input | render | depth at the input resolution.
    """
    from gsslam.run.render import save_intrinsics  # torch: only when there is a map

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
    todo = sorted(set(kfs) | set(others))
    log.info("evaluating the map on %d frames at %dx%d and %dx%d", len(todo), mapper.intrinsics.width,
             mapper.intrinsics.height, pipe.intrinsics.width, pipe.intrinsics.height)  # fmt: skip

    def tick(k: int) -> None:
        if progress is not None:
            progress("outputs: map metrics", k, len(todo))

    from gsslam.mapping.outputs import evenly_spaced

    native_kfs = evenly_spaced(kfs, pipe.cfg.run.native_eval_keyframes)
    native_others = evenly_spaced(others, pipe.cfg.run.native_eval_held_out)
    native_only = set(native_kfs) | set(native_others)
    ev = (
        mapper.evaluate((ds[i] for i in todo), poses, native=True, progress=tick, native_only=native_only)
        if todo
        else {}
    )
    per_frame = ev.pop("per_frame_psnr", {})
    if todo:
        ev["native_frames"] = {"keyframes": native_kfs, "held_out": native_others}
        native_psnr = sorted(ev.get("per_frame_psnr_native", {}).items())
        ev["per_frame_psnr_native"] = {str(i): float(p) for i, p in native_psnr}
    worst = sorted((p, i) for i, p in per_frame.items() if i in set(kfs))[:panels_worst]
    for p, i in worst:  # where the map is weak, at the input's resolution
        mapper.native_panel(ds[i], poses[i], out / "renders" / f"worst_{i:06d}_{p:.1f}dB.png")
    ev["worst_keyframes"] = [{"frame": i, "psnr": p} for p, i in worst]
    refined = stage.refined_keyframe_poses
    # the map after the joint refinement, seen from its own refined keyframe poses (one chain only)
    if refined and kfs and one_world(pipe):
        ev_r = mapper.evaluate((ds[i] for i in kfs), {i: refined[i] for i in kfs if i in refined})
        ev["psnr_keyframes_refined_poses"] = ev_r["psnr_keyframes"]
        ev["ssim_keyframes_refined_poses"] = ev_r["ssim_keyframes"]
        gt = ds.ground_truth()
        align = "sim3" if pipe.monocular else "se3"
        refined_cam = trajectory_of(pipe, camera.apply(refined, pipe.timestamps))  # the ground truth's camera
        ev["ate_keyframes_refined_poses"], _ = ate_metrics(gt, refined_cam, align)
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
