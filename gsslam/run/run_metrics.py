"""The numbers of one finished run folder, as one flat table row (reads files, computes with gsslam.eval).

A run folder holds what ``run_sequence`` writes (``trajectory.tum``, ``keyframes.tum``, ``metrics.json``)
plus ``groundtruth.tum`` written by the batch worker from the dataset. From them :func:`evaluate_run`
takes the runner's numbers (ATE, loops, map, FPS, peak RSS, wall time) and computes what the runner does
not report: the Sim(3) scale (also of an RGB-D run: its metric scale error), RPE over one frame and, for
KITTI, t_rel / r_rel. A value nobody measured is ``None`` (printed as a dash).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

from gsslam.errors import GsslamError

log = logging.getLogger(__name__)


def _rmse(d: dict | None) -> float | None:
    return None if not d else d.get("rmse_m")


def _trajectory_metrics(gt, traj, align: str, kitti: bool) -> dict[str, Any]:
    from gsslam.eval.ate import compute_ate
    from gsslam.eval.kitti import kitti_relative_errors
    from gsslam.eval.rpe import compute_rpe

    out: dict[str, Any] = {}
    try:
        res_sim3, _ = compute_ate(gt, traj, align="sim3")
        out["sim3_scale"] = res_sim3.alignment.scale
        res, assoc = compute_ate(gt, traj, align=align)
        out["ate_recomputed_m"] = res.stats.rmse
        aligned = res.alignment.apply_poses(traj.poses[assoc.est_indices])
        gt_poses = gt.poses[assoc.gt_indices]
        rpe = compute_rpe(gt_poses, aligned, delta=1)
        out["rpe_t_m"], out["rpe_r_deg"] = rpe.translation.rmse, rpe.rotation_deg.rmse
        if kitti:
            k = kitti_relative_errors(gt_poses, aligned)
            out["t_rel_pct"], out["r_rel_deg_per_100m"] = k.t_rel_pct, k.r_rel_deg_per_100m
            out["kitti_segments"] = k.segments
    except GsslamError as e:  # too few poses for an alignment or an RPE: the row keeps what it has
        log.warning("trajectory metrics incomplete: %s", e)
    return out


def evaluate_run(run_dir: Path, kitti: bool = False) -> dict[str, Any]:
    """The row of the run in ``run_dir``; ``kitti``: also t_rel / r_rel (a KITTI sequence)."""
    from gsslam.io.trajectory import read_tum

    run_dir = Path(run_dir)
    m = json.loads((run_dir / "metrics.json").read_text())
    mode = m.get("mode")
    align = "sim3" if mode == "mono" else "se3"
    mp = m.get("mapper") or {}
    lp = m.get("loop_closure") or {}
    row: dict[str, Any] = {
        "mode": mode,
        "frames": m.get("frames"),
        "frames_posed": m.get("frames_posed"),
        "keyframes": m.get("keyframes"),
        "align": align,
        "ate_m": _rmse(m.get("ate")),
        "ate_kf_m": _rmse(m.get("ate_keyframes")),
        "ate_online_m": _rmse(m.get("ate_online")),
        "ate_before_batch_m": _rmse(m.get("ate_before_batch")),
        "sim3_scale": None,
        "rpe_t_m": None,
        "rpe_r_deg": None,
        "t_rel_pct": None,
        "r_rel_deg_per_100m": None,
        "loops_enabled": bool(lp.get("enabled")),
        "loops_detected": lp.get("detected") if lp.get("enabled") else None,
        "loops_accepted": lp.get("accepted") if lp.get("enabled") else None,
        "loops_rejected": lp.get("rejected") if lp.get("enabled") else None,
        "psnr": mp.get("psnr_keyframes"),
        "psnr_held_out": mp.get("psnr_other"),
        "ssim": mp.get("ssim_keyframes"),
        "map_mb": mp.get("ply_mb", mp.get("size_mb")),
        "fps": m.get("fps"),
        "peak_rss_mb": m.get("peak_rss_mb"),
        "wall_s": m.get("wall_time_s"),
        "backend": mp.get("rasterizer_backend", mp.get("backend")),
        "tracking_events": len(m.get("events", [])),
    }
    gt_file, traj_file = run_dir / "groundtruth.tum", run_dir / "trajectory.tum"
    if gt_file.is_file() and traj_file.is_file():
        gt, traj = read_tum(gt_file), read_tum(traj_file)
        if len(gt) and len(traj) >= 3:
            row.update(_trajectory_metrics(gt, traj, align, kitti))
    return row
