"""Checkpoints of a whole run: written atomically into the run folder, resumed with ``--resume``.

Layout (``OUT/checkpoint/``)::

    latest.json            {"name": "ck-000024"}: the last COMPLETE checkpoint (replaced by a rename)
    ck-000024/manifest.json  format, version, config hash, dataset identity, position, file hashes
    ck-000024/state.json     the pipeline's object tree (:mod:`gsslam.run.state_codec`)
    ck-000024/arrays.npz     every array and tensor of the state (loaded with ``allow_pickle=False``)

A checkpoint is written into a hidden temporary folder, renamed to ``ck-NNNNNN`` (NNNNNN: the next
frame to process) and only then named by ``latest.json``; older ones are removed after that. A run
killed at any moment (SIGKILL included) leaves the previous complete checkpoint in place.

The graphs are stored as their backends' replay logs (factor specs, values, updates; see
:meth:`gsslam.graph.backend.Backend.replay`): loading rebuilds every iSAM2 by replaying them.
Loading refuses, with one line: another format or version, a file whose hash does not match the
manifest, a config (``run.*`` aside) or dataset other than the run's.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import time
from pathlib import Path
from typing import Any

import numpy as np

from gsslam.config import Config, config_to_dict
from gsslam.errors import GsslamError
from gsslam.io.atomic import TMP_MARK, atomic_write_text
from gsslam.run.state_codec import StateCodecError, StateDecoder, StateEncoder, dumps

log = logging.getLogger(__name__)

FORMAT = "gsslam-checkpoint"
VERSION = 1
CHECKPOINT_DIR = "checkpoint"
LATEST = "latest.json"
FILES = ("state.json", "arrays.npz")


class CheckpointError(GsslamError):
    """No checkpoint to resume from, or one that cannot be used (corrupt, foreign, another run's)."""


# ---- identity -----------------------------------------------------------------------------------


def resume_config_hash(cfg: Config) -> str:
    """SHA-256 of the config without the ``run`` section (how often to checkpoint may change)."""
    d = config_to_dict(cfg)
    d.pop("run", None)
    return hashlib.sha256(json.dumps(d, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def dataset_identity(ds, dataset_path: str | None) -> dict:
    """What must match for a checkpoint to continue on ``ds``: loader, path, length, camera."""
    intr = ds.intrinsics
    return {
        "loader": type(ds).__name__,
        "name": getattr(ds, "name", None),
        "path": dataset_path,
        "frames": len(ds),
        "camera": [intr.width, intr.height, intr.fx, intr.fy, intr.cx, intr.cy],
    }


# ---- the state's types --------------------------------------------------------------------------


def _classes() -> tuple[list[type], tuple[type, ...]]:
    """(classes a checkpoint may construct, resource types taken from the fresh pipeline)."""
    from gsslam import config
    from gsslam.frontend.flow import DISFlow, FarnebackFlow
    from gsslam.frontend.keyframes import KeyframeSelector
    from gsslam.frontend.mono_encoder import MonoEncoder
    from gsslam.frontend.rgbd_encoder import ColourDepthCheck, RGBDEncoder
    from gsslam.frontend.rgbd_tracking import MotionPrior
    from gsslam.frontend.tracking import FrameMatches, FrameTracker, TrackStatus
    from gsslam.graph.backend import Backend
    from gsslam.graph.submap_graph import SubmapGraph
    from gsslam.loop.detector import LoopDetector
    from gsslam.loop.types import LoopCandidate, LoopConstraint, LoopStats, SubmapRecord, ViewFeatures
    from gsslam.slam.chains import Chain, ChainKeyframe, Event
    from gsslam.slam.cross_flow import CrossFlowFeed
    from gsslam.slam.loop_stage import LoopStage
    from gsslam.slam.pipeline import Pipeline
    from gsslam.types import CameraIntrinsics, Correspondences, Frame, SubmapEncoding

    classes = [
        Pipeline, Chain, ChainKeyframe, Event, CrossFlowFeed, LoopStage, SubmapGraph, Backend,
        KeyframeSelector, MonoEncoder, RGBDEncoder, ColourDepthCheck, FrameTracker, FrameMatches,
        TrackStatus, LoopDetector, LoopStats, SubmapRecord, ViewFeatures, LoopCandidate, LoopConstraint,
        CameraIntrinsics, Frame, SubmapEncoding, Correspondences, MotionPrior,
    ]  # fmt: skip
    resources = (
        config.Config, config.FlowConfig, config.KeyframeConfig, config.EncoderConfig, config.GraphConfig,
        config.MapperConfig, config.LoopConfig, config.PipelineConfig, config.RunConfig,
        DISFlow, FarnebackFlow,
    )  # fmt: skip
    import sys

    if "torch" in sys.modules:  # the map's classes (torch is imported only when the map is on)
        from gsslam.mapping.densify import DensifyStrategy
        from gsslam.mapping.gaussians import GaussianModel
        from gsslam.mapping.keyframes import Keyframe
        from gsslam.mapping.mapper import GaussianMapper
        from gsslam.mapping.registration import Registration
        from gsslam.mapping.state import MapState
        from gsslam.slam.map_stage import MapStage

        classes += [
            MapStage,
            GaussianMapper,
            MapState,
            DensifyStrategy,
            GaussianModel,
            Keyframe,
            Registration,
        ]
    return classes, resources


def _encode_backend(backend, enc: StateEncoder) -> dict:
    return {
        "config": enc.encode(backend.config, "backend.config"),
        "log": enc.encode(backend.replay_log(), "backend.log"),
    }


def _decode_backend(data: dict, dec: StateDecoder):
    from gsslam.graph.backend import Backend
    from gsslam.graph.factor_specs import build_factor

    backend = Backend.from_config(dec.decode(data["config"]))
    backend.replay(dec.decode(data["log"]), build_factor)
    return backend


# ---- writing ------------------------------------------------------------------------------------


def save_checkpoint(out: Path, pipe, position: dict, identity: dict) -> dict:
    """Write the pipeline's state + ``position`` (next frame, frames done, seconds) atomically.

    Returns ``{"name", "bytes", "seconds"}``. Raises :class:`CheckpointError` when the state holds
    something that cannot be stored (e.g. a plugin's factor without a spec).
    """
    from gsslam.graph.backend import Backend, BackendError

    t0 = time.perf_counter()
    classes, resources = _classes()
    enc = StateEncoder(classes, resources, hooks={Backend: _encode_backend})
    try:
        tree = enc.encode(pipe, "pipe")
    except (StateCodecError, BackendError) as e:
        raise CheckpointError(f"cannot checkpoint this run: {e}") from e
    root = Path(out) / CHECKPOINT_DIR
    root.mkdir(exist_ok=True)
    name = f"ck-{int(position['next_frame']):06d}"
    tmp = root / f".{name}{TMP_MARK}{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    try:
        _write_file(
            tmp / "state.json",
            dumps({"pipeline": tree, "resources": sorted(enc.resources.values())}).encode(),
        )
        with open(tmp / "arrays.npz", "wb") as fh:
            np.savez(fh, **enc.arrays)
            fh.flush()
            os.fsync(fh.fileno())
        manifest = {
            "format": FORMAT,
            "version": VERSION,
            "config_sha256": identity["config_sha256"],
            "dataset": identity["dataset"],
            "position": position,
            "files": {f: _sha256(tmp / f) for f in FILES},
        }
        _write_file(tmp / "manifest.json", json.dumps(manifest, indent=1).encode())
        final = root / name
        if final.exists():
            shutil.rmtree(final)
        os.replace(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    atomic_write_text(root / LATEST, json.dumps({"name": name}))
    for p in root.iterdir():  # older checkpoints and temporary folders of killed writers
        if p.is_dir() and p.name != name:
            shutil.rmtree(p, ignore_errors=True)
    size = sum(f.stat().st_size for f in final.iterdir())
    seconds = time.perf_counter() - t0
    log.info("checkpoint %s: %.1f MB in %.2f s", name, size / 1e6, seconds)
    return {"name": name, "bytes": size, "seconds": seconds}


def _write_file(path: Path, data: bytes) -> None:
    with open(path, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def remove_checkpoints(out: Path) -> None:
    shutil.rmtree(Path(out) / CHECKPOINT_DIR, ignore_errors=True)


# ---- reading ------------------------------------------------------------------------------------


def read_manifest(out: Path) -> tuple[Path, dict]:
    """The folder of the last complete checkpoint in ``out`` and its checked manifest."""
    root = Path(out) / CHECKPOINT_DIR
    latest = root / LATEST
    if not latest.is_file():
        raise CheckpointError(f"{out} holds no checkpoint to resume from (no {CHECKPOINT_DIR}/{LATEST})")
    try:
        name = json.loads(latest.read_text())["name"]
        if not isinstance(name, str) or not name.startswith("ck-") or "/" in name or name != Path(name).name:
            raise ValueError(f"bad checkpoint name {name!r}")
        folder = root / name
        manifest = json.loads((folder / "manifest.json").read_text())
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise CheckpointError(
            f"the checkpoint in {root} is unreadable ({e}); rerun without --resume"
        ) from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise CheckpointError(f"{folder} is not a gsslam checkpoint; rerun without --resume")
    if manifest.get("version") != VERSION:
        raise CheckpointError(
            f"{folder} is a version {manifest.get('version')} checkpoint; this gsslam reads version "
            f"{VERSION} only: rerun without --resume"
        )
    files = manifest.get("files")
    if not isinstance(files, dict) or not isinstance(manifest.get("position"), dict):
        raise CheckpointError(f"{folder}/manifest.json is malformed; rerun without --resume")
    for f in FILES:
        expected = files.get(f)
        if not (folder / f).is_file() or _sha256(folder / f) != expected:
            raise CheckpointError(
                f"{folder / f} is missing or corrupt (hash mismatch); rerun without --resume"
            )
    return folder, manifest


def check_identity(manifest: dict, identity: dict, folder: Path) -> None:
    if manifest.get("config_sha256") != identity["config_sha256"]:
        raise CheckpointError(
            f"the checkpoint in {folder.parent} was written with another config; resume with the run's "
            "config (see its config.yaml) or rerun without --resume"
        )
    if manifest.get("dataset") != identity["dataset"]:
        raise CheckpointError(
            f"the checkpoint in {folder.parent} is of another dataset ({manifest.get('dataset')}); "
            "resume on the run's dataset or rerun without --resume"
        )


def load_checkpoint(out: Path, fresh_pipe, identity: dict) -> tuple[Any, dict]:
    """``(pipeline, position)`` from the last complete checkpoint in ``out``.

    ``fresh_pipe``: a pipeline just built from the run's config; it provides the resources (config,
    flow estimator). No code is loaded from the files: JSON, and arrays with ``allow_pickle=False``.
    """
    from gsslam.graph.backend import Backend

    folder, manifest = read_manifest(out)
    check_identity(manifest, identity, folder)
    try:
        state = json.loads((folder / "state.json").read_text())
        with np.load(folder / "arrays.npz", allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, json.JSONDecodeError) as e:
        raise CheckpointError(f"{folder} cannot be read ({e}); rerun without --resume") from None
    classes, _ = _classes()

    def resolve(path: str):
        obj = fresh_pipe
        parts = path.split(".")
        if parts[0] != "pipe" or not all(p.isidentifier() and not p.startswith("__") for p in parts):
            raise CheckpointError(f"{folder}: bad resource name {path!r}")
        for p in parts[1:]:
            obj = getattr(obj, p, None)
        if obj is None:
            raise CheckpointError(f"{folder}: the new pipeline has no {path}; rerun without --resume")
        return obj

    dec = StateDecoder(classes, arrays, resolve, hooks={Backend: _decode_backend})
    try:
        pipe = dec.decode(state["pipeline"])
    except (StateCodecError, KeyError, TypeError) as e:
        raise CheckpointError(f"{folder} does not decode: {e}; rerun without --resume") from None
    if type(pipe) is not type(fresh_pipe):
        raise CheckpointError(f"{folder} does not hold a pipeline; rerun without --resume")
    pos = manifest["position"]
    try:
        position = {
            "next_frame": int(pos["next_frame"]),
            "frames_done": int(pos["frames_done"]),
            "seconds": float(pos["seconds"]),
        }
    except (KeyError, TypeError, ValueError):
        raise CheckpointError(f"{folder}/manifest.json: bad position {pos}; rerun without --resume") from None
    return pipe, position


def submap_count(pipe) -> int:
    return sum(len(c.encodings) for c in pipe.chains)


class CheckpointSchedule:
    """Writes a checkpoint every ``every`` new submaps (and when asked to, at an interruption)."""

    def __init__(self, out: Path, every: int, identity: dict, submaps: int) -> None:
        self.out, self.every, self.identity = out, every, identity
        self.last_submaps = submaps
        self.written: list[dict] = []
        self.error: str | None = None  # why this run cannot be checkpointed (it goes on without)

    def after_frame(self, pipe, position: dict, final: bool = False) -> None:
        if self.every <= 0 or self.error is not None:
            return
        n = submap_count(pipe)
        if final or n >= self.last_submaps + self.every:
            try:
                self.written.append(save_checkpoint(self.out, pipe, position, self.identity))
            except CheckpointError as e:
                self.error = str(e)
                log.warning("%s; the run goes on without checkpoints", e)
            self.last_submaps = n

    def summary(self) -> dict:
        w = self.written
        return {
            "every_submaps": self.every,
            "written": len(w),
            "last": w[-1]["name"] if w else None,
            "bytes_last": w[-1]["bytes"] if w else 0,
            "seconds_total": sum(c["seconds"] for c in w),
            "error": self.error,
        }
