"""Run a whole sequence through :class:`gsslam.slam.pipeline.Pipeline` and write the results.

Files in ``out`` (written by :mod:`gsslam.run.outputs`): ``trajectory.tum`` (every frame that has a
pose, dataset timestamps), ``keyframes.tum``, ``config.yaml`` (the resolved config), ``metrics.json``
(ATE when the dataset has ground truth: Sim(3)-aligned for mono, SE(3) for RGB-D; counts, wall time,
FPS, peak RSS, tracking-loss events, provenance) and ``trajectory.png``. They are written in a
``finally`` so that an interrupted run (Ctrl-C, SIGTERM through the CLI) still leaves the trajectory
estimated so far. The folder is a :class:`gsslam.run.folder.RunFolder`: locked for the run, refused
when it holds another run (unless ``overwrite``). ``metrics.json`` is written first with
``"status": "running"`` and rewritten as the outputs progress (see :mod:`gsslam.run.outputs`).

Checkpoints (:mod:`gsslam.run.checkpoint`): every ``run.checkpoint_every`` new submaps, and when
SIGINT/SIGTERM arrives during the frames (the current frame is finished first; a second signal
interrupts at once), the whole run state is written to ``out/checkpoint/``; ``resume=True`` continues
from the last complete one. A run that finishes removes its checkpoint.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from gsslam.config import Config, save_config, validate_config
from gsslam.datasets import open_dataset
from gsslam.datasets.frame_range import FrameRange
from gsslam.datasets.prefetch import FramePrefetcher
from gsslam.errors import GsslamError
from gsslam.frontend.depth_registration import register_frame
from gsslam.frontend.depth_retiming import DepthRetimer
from gsslam.frontend.mono_focal import rescale_focal
from gsslam.frontend.registration_record import registration_record
from gsslam.run.checkpoint import (
    CheckpointSchedule,
    dataset_identity,
    load_checkpoint,
    remove_checkpoints,
    resume_config_hash,
    submap_count,
)
from gsslam.run.folder import RunFolder
from gsslam.run.interrupt import DeferredInterrupt
from gsslam.run.memory import HeapTrimmer, reset_peak_rss
from gsslam.run.outputs import write_metrics, write_outputs
from gsslam.run.provenance import provenance
from gsslam.run.registration import applied_delay, colour_registration, mono_focal_calibration
from gsslam.run.trajectory_camera import trajectory_camera
from gsslam.slam.pipeline import Pipeline
from gsslam.types import StageProgress

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
            if "psnr_keyframes_native" in mp:
                rows.append(
                    (
                        "map (native)",
                        f"PSNR {mp['psnr_keyframes_native']:.1f} dB keyframes / "
                        f"{mp['psnr_other_native']:.1f} dB held-out, SSIM {mp['ssim_keyframes_native']:.3f} "
                        f"({mp['native_width']}x{mp['native_height']})",
                    )
                )
        if mp.get("final_seconds") is not None and m.get("wall_time_s"):
            rows.append(
                (
                    "final pass",
                    f"{mp['final_iterations']} steps, {mp['final_seconds']:.1f} s "
                    f"({100 * mp['final_seconds'] / m['wall_time_s']:.0f} % of the run)",
                )
            )
        lp = m.get("loop_closure") or {}
        if lp.get("enabled"):
            rows.append(
                ("loops", f"{lp['detected']} detected, {lp['accepted']} accepted, {lp['rejected']} rejected")
            )
        for rec in m.get("ate_per_chain") or []:
            a = rec["ate"]
            value = (
                f"{100 * a['rmse_m']:.2f} cm ({a['align']}, {a['pairs']} poses)"
                if a
                else "no ground truth pairs"
            )
            rows.append((f"ATE RMSE chain {rec['chain']}", value))
        for key, label in (
            ("ate", "ATE RMSE (all frames)"),
            ("ate_keyframes", "ATE RMSE (keyframes)"),
            ("ate_before_batch", "ATE RMSE (before batch)"),
            ("ate_online", "ATE RMSE (online, as frames arrived)"),
        ):
            if m.get(key):
                rows.append(
                    (label, f"{100 * m[key]['rmse_m']:.2f} cm ({m[key]['align']}, {m[key]['pairs']} poses)")
                )
        if m.get("ate_per_chain"):
            rows.append(("chains", "not joined in one world frame: ATE per chain, no overall number"))
        elif m.get("chains", 0) > 1:
            rows.append(("chains", f"{m['chains']} chains re-localized into one world frame"))
        if m.get("resumed_from_frame") is not None:
            rows.append(("resumed", f"from the checkpoint at frame {m['resumed_from_frame']}"))
        if m.get("interrupted"):
            ck = (m.get("checkpoints") or {}).get("last")
            tail = f"; --resume continues from {ck}" if ck else ""
            rows.append(("interrupted", f"yes: outputs hold the poses estimated so far{tail}"))
        rows.append(("outputs", str(self.out)))
        return rows


def run_sequence(
    path: str | Path,
    dataset_name: str,
    cfg: Config,
    out: str | Path,
    max_frames: int | None = None,
    progress: bool | ProgressCallback = True,
    overwrite: bool = False,
    stages: StageProgress | None = None,
    start_frame: int = 0,
    resume: bool = False,
    **dataset_kwargs: Any,
) -> RunResult:
    """Open the dataset ``dataset_name`` at ``path`` and run :func:`run_dataset` on it.

    ``progress``: a callback ``(done, total, fps)`` called after every frame (the CLI draws a
    progress bar with it); ``True``/``False`` without a callback report nothing (the library never prints).
    The dataset is opened (and its files checked) before ``out`` is touched.
    ``stages``: a callback ``(stage, done, total)`` for the stages after tracking (batch refinement,
    final pass, outputs).
    ``start_frame``: skip the sequence's first frames (the run and ``max_frames`` count from there).
    ``resume``: continue the run in ``out`` from its last checkpoint.
    """
    if cfg.mode == "mono" and dataset_name in DATASETS_WITH_OPTIONAL_DEPTH:
        # a monocular run reads no depth, so frames that only lack a depth image are kept
        dataset_kwargs.setdefault("with_depth", False)
    ds = open_dataset(dataset_name, path, **dataset_kwargs)
    if start_frame:
        ds = FrameRange(ds, start_frame)
    callback = progress if callable(progress) else None
    prov = provenance(cfg, path)
    if start_frame:
        prov["start_frame"] = start_frame
    return run_dataset(
        ds, cfg, Path(out), max_frames=max_frames, progress=callback, stages=stages, overwrite=overwrite,
        provenance=prov, resume=resume,
    )  # fmt: skip


def run_dataset(
    ds,
    cfg: Config,
    out: Path,
    max_frames: int | None = None,
    progress: ProgressCallback | None = None,
    overwrite: bool = False,
    provenance: dict | None = None,
    stages: StageProgress | None = None,
    resume: bool = False,
) -> RunResult:
    """Run the pipeline over the first ``max_frames`` frames of ``ds``; write the outputs to ``out``.

    ``overwrite``: replace gsslam's files of an older run in ``out`` (else such a folder is refused).
    ``resume``: continue the run in ``out`` from its last complete checkpoint (same config, ``run.*``
    aside, and same dataset, else :class:`gsslam.run.checkpoint.CheckpointError`); the frames before
    it are not read again.
    ``progress(done, total, fps)`` after every frame; ``stages(stage, done, total)`` during the stages
    after the frames (each also logged at INFO).
    ``provenance``: the record for ``metrics.json`` (default: :func:`gsslam.run.provenance.provenance`).
    """
    validate_config(cfg)  # a config built in Python has not been through load_config
    if max_frames is not None and max_frames < 1:
        raise RunError(f"max_frames must be >= 1, got {max_frames}")
    if resume and overwrite:
        raise RunError("--resume continues the run in the output folder; --overwrite would remove it")
    out = Path(out)
    prov = provenance if provenance is not None else _default_provenance(cfg, ds)
    identity = {
        "config_sha256": resume_config_hash(cfg),
        "dataset": dataset_identity(ds, prov.get("dataset_path")),
    }
    imu_stage = None
    if cfg.imu.enabled:  # before the folder is touched: a dataset without IMU fails here
        from gsslam.run.imu import make_imu_stage

        imu_stage = make_imu_stage(cfg, ds)
    with RunFolder(out, overwrite=overwrite, resume=resume):
        rss_scope = "run" if reset_peak_rss() else "process"  # a batch runs many in one process
        reg, focal = colour_registration(ds, cfg, max_frames)  # deterministic: a resumed run finds the same
        reg = replace(
            reg, depth_mean_tol=cfg.encoder.colour_registration_depth_mean_tol,
            depth_interp_tol=cfg.encoder.colour_registration_depth_interp_tol,
            delay_s=applied_delay(cfg, focal),
        )  # fmt: skip
        retimer = None
        if reg.delay_s:  # session 18: the first frames primed, the velocity from the raw depth (options)
            enc = cfg.encoder
            retimer = DepthRetimer(
                reg.delay_s, enc.depth_delay_velocity_frames, reg.depth_intrinsics(ds.intrinsics),
                reg.T_colour_depth(), raw_velocity=enc.depth_delay_velocity == "depth",
            )  # fmt: skip
        if not reg.is_identity() and cfg.encoder.colour_registration_icp:  # unregistered depth: re-projected
            cfg = replace(cfg, encoder=replace(cfg.encoder, rgbd_icp=True))  # poses from depth (ICP)
        mono_scale, mono_focal = mono_focal_calibration(ds, cfg, max_frames)  # 1.0: the given focal stays
        camera = trajectory_camera(  # the camera trajectory.tum is (7-Scenes' ground truth: the depth one)
            cfg.run.trajectory_camera, ds, None if reg.is_identity() else reg.T_colour_depth(), reg.delay_s
        )
        pipe = Pipeline(cfg, reg.colour_intrinsics(ds.intrinsics).with_focal(mono_scale))
        if imu_stage is not None:
            pipe.add_plugin(imu_stage)
        start, done, seconds_before, load_seconds = 0, 0, 0.0, None
        if resume:
            t_load = time.perf_counter()
            pipe, position = load_checkpoint(out, pipe, identity)
            load_seconds = time.perf_counter() - t_load  # reading + the graphs' replay
            start, done = int(position["next_frame"]), int(position["frames_done"])
            seconds_before = float(position["seconds"])
            prov = {**prov, "resumed_from_frame": start}
            log.info("resuming at frame %d from the checkpoint in %s", start, out)
        save_config(cfg, out / "config.yaml")
        write_metrics(out, {"status": "running", "provenance": prov, "dataset": getattr(ds, "name", None)})
        n = len(ds) if max_frames is None else min(len(ds), max_frames)
        result = RunResult(out)
        ckpt = CheckpointSchedule(out, cfg.run.checkpoint_every, identity, submap_count(pipe))
        trimmer = HeapTrimmer(cfg.run.trim_heap, submap_count(pipe))  # free heap pages back after each submap
        t0 = time.perf_counter()
        interrupted = True
        before_batch: dict[int, np.ndarray] = {}
        try:
            if retimer is not None and cfg.encoder.depth_delay_prime and start + 1 < n:
                f0, f1 = ds[start], ds[start + 1]  # the first frames' velocity, one frame read ahead
                retimer.prime(f0.timestamp, f0.depth, f1.timestamp, f1.depth)
            with DeferredInterrupt() as stop, FramePrefetcher(ds, range(start, n)) as frames:
                # decoding overlaps tracking; same order as ds[i]
                for i, frame in zip(range(start, n), frames):
                    D = None if retimer is None else retimer.motion(frame.timestamp, frame.depth)
                    pose = pipe.process(rescale_focal(register_frame(frame, reg, D), mono_scale))
                    if retimer is not None:
                        retimer.observe(frame.timestamp, pose)
                    done += 1
                    if progress is not None:
                        progress(done, n, done / max(time.perf_counter() - t0 + seconds_before, 1e-9))
                    position = {
                        "next_frame": i + 1,
                        "frames_done": done,
                        "seconds": seconds_before + time.perf_counter() - t0,
                    }
                    ckpt.after_frame(pipe, position, final=stop.signum is not None)
                    trimmer.after(submap_count(pipe))
                    stop.deliver_pending()
            pipe.close_chain()  # the tail's submap: the poses before the batch refinement are complete
            before_batch = pipe.frame_poses()
            log.info("%d frames tracked in %.1f s; finishing", done, time.perf_counter() - t0)
            pipe.finish(run_seconds=seconds_before + time.perf_counter() - t0, progress=stages)
            interrupted = False
        finally:
            wall = seconds_before + time.perf_counter() - t0
            trimmer.now()  # what the final pass freed, before the outputs render and evaluate
            if stages is not None:
                stages("outputs", 0, 1)
            extra = {
                "resumed_from_frame": start if resume else None,
                "checkpoints": {**ckpt.summary(), "load_seconds": load_seconds},
                "peak_rss_scope": rss_scope,
            }
            if retimer is not None:
                extra["depth_retiming"] = retimer.record()
            if focal is not None or reg.given_by_config:
                extra["colour_focal"] = registration_record(reg, focal)
            check = getattr(pipe.encoder, "check", None)  # RGB-D: the encoder's ColourDepthCheck
            if check is not None:
                extra["colour_depth_check"] = {
                    "pairs": check.pairs, "pnp_icp_rotation_ratio": check.ratio,
                    "latched": check.mismatch, "latched_at_pair": getattr(check, "latched_at", 0),
                }  # fmt: skip
            if mono_focal is not None:
                extra["mono_focal"] = {
                    "scale_estimated": mono_focal.scale, "applied": mono_scale != 1.0, "ok": mono_focal.ok,
                    "windows": mono_focal.windows, "agreeing": mono_focal.agreeing, "gain": mono_focal.gain,
                }  # fmt: skip
            if imu_stage is not None:
                from gsslam.run.imu import imu_metrics

                extra["imu"] = imu_metrics(imu_stage, pipe, ds.ground_truth())
            result.metrics = write_outputs(
                pipe, ds, out, wall, done, interrupted, before_batch, prov, progress=stages, extra=extra,
                camera=camera,
            )  # fmt: skip
        remove_checkpoints(out)  # the run is complete: nothing to resume
    return result


class RunError(GsslamError):
    """A run was asked for with arguments that cannot work."""


def _default_provenance(cfg: Config, ds) -> dict:
    return provenance(cfg, getattr(ds, "root", None))
