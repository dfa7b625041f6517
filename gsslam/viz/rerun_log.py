"""A rerun recording (``.rrd``) of a run folder: open it with ``gsslam view RUN`` or ``rerun RUN/run.rrd``.

Written from the files a run leaves (``trajectory.tum``, ``keyframes.tum``, ``keyframes/*.jpg``,
``intrinsics.yaml``, ``map.ply``, ``metrics.json``) after the run, so the pipeline never imports
rerun (extra ``viz``: ``pip install 'gsslam[viz]'``). Entities, world frame = the run's world
(OpenCV camera axes, right-down-forward; units as the run: metres for RGB-D, arbitrary for mono):

- ``world/trajectory``: the camera path (static line strip);
- ``world/camera``: the camera pose and pinhole on the ``frame`` / ``time`` timelines;
- ``world/keyframes/<k>``: a frustum per keyframe with its image (static);
- ``world/map/gaussians``: the Gaussians as ellipsoids (1 sigma half-sizes, DC colour, alpha =
  opacity) and ``world/map/points`` their means as points (static);
- ``metrics/step_translation``, ``metrics/step_rotation_deg``: the motion between consecutive
  frames, per frame; ``log/events``: tracking events and loop-closure decisions as text at their
  frame; ``summary``: metrics.json as a text document.

Loop closures are logged as text only: the run folder records them by submap id, not by frame.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from gsslam.errors import GsslamError

log = logging.getLogger(__name__)


class RerunLogError(GsslamError):
    """rerun is not installed, or the run folder lacks what the recording needs."""


def _import_rerun():
    try:
        import rerun as rr
    except ImportError:
        raise RerunLogError(
            "the rerun viewer needs rerun-sdk: pip install 'gsslam[viz]' (or pip install rerun-sdk)"
        ) from None
    return rr


def _rotation_deg(R: np.ndarray) -> float:  # R [3, 3]
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))))


def record_run(run_dir: str | Path, out_rrd: str | Path, max_gaussians: int | None = 200_000) -> Path:
    """Write ``out_rrd`` from the run folder ``run_dir``; returns its path.

    ``max_gaussians``: log at most this many Gaussians (the most opaque ones); None logs all.
    """
    rr = _import_rerun()
    from gsslam.io.trajectory import read_tum
    from gsslam.run.keyframes import KEYFRAME_DIR, find_keyframe_images
    from gsslam.run.render import load_intrinsics
    from gsslam.run.trajectory_camera import image_poses_file

    run_dir, out_rrd = Path(run_dir), Path(out_rrd)
    if not (run_dir / "trajectory.tum").is_file():
        raise RerunLogError(f"{run_dir / 'trajectory.tum'} not found; pass the folder a `gsslam run` wrote")
    traj = read_tum(run_dir / "trajectory.tum")
    kf_file = image_poses_file(run_dir, "keyframes")  # the colour camera's, which the keyframe images are
    kf = read_tum(kf_file) if kf_file.is_file() else None
    intr = load_intrinsics(run_dir / "intrinsics.yaml") if (run_dir / "intrinsics.yaml").is_file() else None
    metrics = (
        json.loads((run_dir / "metrics.json").read_text()) if (run_dir / "metrics.json").is_file() else {}
    )

    rec = rr.RecordingStream("gsslam", recording_id=str(run_dir.resolve()))
    out_rrd.parent.mkdir(parents=True, exist_ok=True)
    rec.save(out_rrd, default_blueprint=_blueprint())
    rec.log("world", rr.ViewCoordinates.RDF, static=True)
    rec.log("summary", rr.TextDocument(json.dumps(metrics, indent=2), media_type="text/plain"), static=True)
    rec.log("world/trajectory", rr.LineStrips3D([traj.positions], colors=[[255, 140, 0]]), static=True)

    def pinhole(plane: float):
        return rr.Pinhole(
            focal_length=[intr.fx, intr.fy],
            principal_point=[intr.cx, intr.cy],
            resolution=[intr.width, intr.height],
            camera_xyz=rr.ViewCoordinates.RDF,
            image_plane_distance=plane,
        )

    scale = (
        float(np.median(np.linalg.norm(np.diff(traj.positions, axis=0), axis=1))) if len(traj) > 1 else 0.1
    )
    plane = max(10 * scale, 1e-3)  # frustums a few steps long, whatever the units
    if kf is not None:
        images = find_keyframe_images(run_dir / KEYFRAME_DIR)
        for k, (t, T) in enumerate(zip(kf.timestamps, kf.poses)):
            path = f"world/keyframes/{k}"
            rec.log(path, rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]), static=True)
            if intr is not None:
                rec.log(path, pinhole(plane), static=True)
            if float(t) in images:
                rec.log(path, rr.EncodedImage(path=images[float(t)]), static=True)
    if (run_dir / "map.ply").is_file():
        _log_map(rr, rec, run_dir / "map.ply", max_gaussians)
    if intr is not None:
        rec.log("world/camera", pinhole(plane), static=True)

    events: dict[int, list[str]] = {}
    for e in metrics.get("events", []):
        events.setdefault(int(e["frame"]), []).append(f"{e['kind']}: {e['detail']}")
    prev = None
    for k, (t, T) in enumerate(zip(traj.timestamps, traj.poses)):
        rec.set_time("frame", sequence=k)
        rec.set_time("time", timestamp=float(t))
        rec.log("world/camera", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
        if prev is not None:
            d = np.linalg.inv(prev) @ T
            rec.log("metrics/step_translation", rr.Scalars(float(np.linalg.norm(d[:3, 3]))))
            rec.log("metrics/step_rotation_deg", rr.Scalars(_rotation_deg(d[:3, :3])))
        for text in events.get(k, []):
            rec.log("log/events", rr.TextLog(text, level="WARN"))
        prev = T
    for lp in (metrics.get("loop_closure") or {}).get("loops", []):
        state = "accepted" if lp.get("accepted") else f"rejected ({lp.get('why')})"
        rec.log("log/loops", rr.TextLog(f"loop submap {lp.get('i')} -> {lp.get('m')}: {state}"), static=True)
    rec.flush()
    rec.disconnect()
    log.info("rerun recording of %s written to %s", run_dir, out_rrd)
    return out_rrd


def _blueprint():
    """The layout the viewer opens with: the 3D world large, motion plots, events and metrics beside it.

    (A default eye placed behind the first camera, ``rrb.EyeControls3D``, kept rerun 0.41's
    ``--screenshot-to`` from ever finishing under Xvfb, so the viewer's own default eye is used.)
    """
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="world", name="map, trajectory, keyframes"),
            rrb.Vertical(
                rrb.TimeSeriesView(origin="metrics/step_translation", name="translation per frame"),
                rrb.TimeSeriesView(origin="metrics/step_rotation_deg", name="rotation per frame (deg)"),
                rrb.TextLogView(origin="log", name="events"),
                rrb.TextDocumentView(origin="summary", name="metrics.json"),
            ),
            column_shares=[3, 1],
        ),
        collapse_panels=True,
    )


def _log_map(rr, rec, ply: Path, max_gaussians: int | None) -> None:
    from gsslam.io.ply import read_ply

    g = read_ply(ply)
    alpha = 1.0 / (1.0 + np.exp(-g.opacity_logits))  # [N]
    keep = np.argsort(-alpha)[:max_gaussians] if max_gaussians and len(g) > max_gaussians else slice(None)
    rgba = np.concatenate([g.rgb, alpha[:, None]], axis=1)[keep]
    rgba8 = np.round(rgba * 255).astype(np.uint8)
    sigma = np.exp(g.log_scales[keep])  # [N, 3]
    q = g.quats_wxyz[keep][:, [1, 2, 3, 0]]  # rerun quaternions are (x, y, z, w)
    rec.log(
        "world/map/gaussians",
        rr.Ellipsoids3D(
            centers=g.means[keep], half_sizes=sigma, quaternions=q, colors=rgba8, fill_mode="solid"
        ),
        static=True,
    )
    rec.log(
        "world/map/points", rr.Points3D(g.means[keep], colors=rgba8[:, :3], radii=sigma.mean(1)), static=True
    )


def open_viewer(rrd: str | Path) -> None:
    """Open the rerun viewer on ``rrd`` (the ``rerun`` executable shipped with rerun-sdk)."""
    import shutil
    import subprocess
    import sys

    _import_rerun()
    exe = shutil.which("rerun")
    cmd = [exe, str(rrd)] if exe else [sys.executable, "-m", "rerun", str(rrd)]
    subprocess.Popen(cmd)  # the viewer outlives this command
