"""Run a manifest's sequences x configurations, each into its own folder; resume; collect one table.

Layout of ``out``::

    manifest.yaml                    the manifest as run (its resolved plan is in results.json)
    runs/<sequence>__<config>/       run_sequence's outputs + groundtruth.tum + status.json + result.json
    results.md / results.csv / results.json / ate.png

A run is *complete* when its ``result.json`` says ``ok`` for the same plan entry (same data, frames,
loader arguments, overrides: :meth:`RunSpec.fingerprint`); a new ``run_batch`` on the same ``out`` skips
those and runs the rest (failed, interrupted, never started, or changed). A run that raises, or whose
worker process dies, is recorded as ``failed`` with its error and the batch goes on.

Execution: ``jobs == 1`` without an address runs in this process, one run after the other; otherwise
on Ray (optional extra ``gsslam[batch]``): a local Ray with ``jobs`` CPUs, or the cluster at ``address``
(then ``out`` and the data must be on a filesystem every node sees). Each Ray run is a task with
``num_cpus=1`` in a fresh worker process (``max_calls=1``: its own peak RSS) limited to one thread.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import shutil
import socket
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from gsslam.errors import GsslamError
from gsslam.run.manifest import Manifest, RunSpec, data_roots

log = logging.getLogger(__name__)

RESULT_FILE = "result.json"
STATUS_FILE = "status.json"
THREAD_ENV = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


class BatchError(GsslamError):
    """The batch cannot run: Ray is missing for --jobs > 1, a bad option, or unreadable results."""


@dataclass(frozen=True)
class BatchOptions:
    out: Path
    jobs: int = 1
    address: str | None = None
    max_frames: int | None = None  # caps every sequence's frames (a smoke run of a suite)
    data_roots: tuple[Path, ...] = ()
    threads_per_run: int = 1


@dataclass
class BatchResult:
    out: Path
    rows: list[dict]
    executed: list[str] = field(default_factory=list)  # run ids run by this call
    reused: list[str] = field(default_factory=list)  # complete runs found and skipped


def _write_json(path: Path, data: Any) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(data, indent=2, default=str))
    os.replace(tmp, path)  # readers never see half a file


def read_result(run_dir: Path) -> dict | None:
    try:
        return json.loads((run_dir / RESULT_FILE).read_text())
    except (OSError, ValueError):
        return None


def is_complete(run_dir: Path, spec: RunSpec) -> bool:
    rec = read_result(run_dir)
    return rec is not None and rec.get("status") == "ok" and rec.get("fingerprint") == spec.fingerprint()


def _is_kitti(spec: RunSpec) -> bool:
    s = spec.sequence
    return s.dataset == "kitti" or s.kwargs.get("base") == "kitti"


def execute_run(spec: RunSpec, run_dir: str, threads: int | None = None) -> dict:
    """Run one plan entry into ``run_dir`` and return its record (also written to ``result.json``).

    Never raises for a failing run: the error is the record's ``error``. ``threads`` limits torch /
    OpenCV threads (a worker process of its own); ``None`` leaves the caller's settings alone.
    """
    out = Path(run_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / RESULT_FILE).unlink(missing_ok=True)
    started, cpu0 = time.time(), time.process_time()
    base = {
        **spec.to_dict(),
        "fingerprint": spec.fingerprint(),
        "host": socket.gethostname(),
        "pid": os.getpid(),
    }
    status = {
        "state": "running",
        "pid": os.getpid(),
        "host": base["host"],
        "started": started,
        "frames_done": 0,
    }
    _write_json(out / STATUS_FILE, status)
    record: dict[str, Any]
    try:
        if threads is not None:
            import cv2
            import torch

            torch.set_num_threads(threads)
            cv2.setNumThreads(threads)
        record = {**base, **_run_and_evaluate(spec, out, status), "status": "ok", "error": None}
    except Exception as e:  # a failed run is a row of the table, never the end of the batch
        log.warning("run %s failed: %s: %s", spec.run_id, type(e).__name__, e)
        record = {
            **base,
            "status": "failed",
            "error": f"{type(e).__name__}: {e}",
            "traceback": traceback.format_exc(),
        }
    record["started"], record["finished"] = started, time.time()
    record["cpu_s"] = (
        time.process_time() - cpu0
    )  # all threads of this process: wall time on a busy machine lies
    _write_json(out / RESULT_FILE, record)
    _write_json(out / STATUS_FILE, {**status, "state": record["status"], "finished": record["finished"]})
    return record


def _run_and_evaluate(spec: RunSpec, out: Path, status: dict) -> dict:
    from gsslam.config import load_config
    from gsslam.datasets.base import open_dataset
    from gsslam.io.trajectory import write_tum
    from gsslam.run.run_metrics import evaluate_run
    from gsslam.run.sequence import run_sequence  # the one place the batch calls the runner

    s = spec.sequence
    cfg = load_config(None, list(spec.variant.overrides), mode=s.mode)
    kwargs = dict(s.kwargs)
    path = spec.data_path
    if path is None:  # a generated scene: its parameters, as a file the loader reads
        path = out / f"{s.dataset}.yaml"
        path.write_text(yaml.safe_dump(kwargs, sort_keys=False))
        kwargs = {}
    if spec.gt_path is not None:
        kwargs["gt_path"] = spec.gt_path
    last = [0.0]

    def progress(done: int, total: int, fps: float) -> None:
        if time.monotonic() - last[0] > 0.5 or done == total:  # a heartbeat, not a file per frame
            last[0] = time.monotonic()
            _write_json(out / STATUS_FILE, {**status, "frames_done": done, "frames_total": total})

    # a run is re-executed only when it did not complete: its earlier attempt is replaced
    run_sequence(
        path, s.dataset, cfg, out, max_frames=s.frames, progress=progress, overwrite=True,
        start_frame=s.start, **kwargs,
    )  # fmt: skip
    gt_kwargs = dict(kwargs)
    if cfg.mode == "mono" and s.dataset in ("tum", "7scenes"):
        gt_kwargs.setdefault("with_depth", False)  # as the run opened it: same frames, same ground truth
    gt = open_dataset(s.dataset, path, **gt_kwargs).ground_truth()
    if gt is not None:
        write_tum(gt, out / "groundtruth.tum")
    return evaluate_run(out, kitti=_is_kitti(spec))


def _import_ray():
    try:
        import ray
    except ImportError:
        raise BatchError(
            "parallel or cluster batches (--jobs > 1, --address) need Ray: pip install 'gsslam[batch]'; "
            "without it use --jobs 1"
        ) from None
    return ray


def _failed_record(spec: RunSpec, error: str) -> dict:
    return {**spec.to_dict(), "fingerprint": spec.fingerprint(), "status": "failed", "error": error}


def _run_ray(todo: list[tuple[RunSpec, Path]], opts: BatchOptions, on_done: Callable[[dict], None]) -> None:
    ray = _import_ray()
    started_here = not ray.is_initialized()
    if started_here:
        env = {"env_vars": {k: str(opts.threads_per_run) for k in THREAD_ENV}}
        if opts.address:
            ray.init(address=opts.address, runtime_env=env, log_to_driver=True)
        else:
            ray.init(num_cpus=opts.jobs, include_dashboard=False, runtime_env=env, log_to_driver=True)
    remote = ray.remote(num_cpus=opts.threads_per_run, max_calls=1, max_retries=0)(execute_run)
    try:
        pending = {remote.remote(spec, str(d), opts.threads_per_run): (spec, d) for spec, d in todo}
        while pending:
            # a timeout lets Python see Ctrl-C between waits (a blocking wait would swallow it)
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=1.0)
            if not ready:
                continue
            spec, run_dir = pending.pop(ready[0])
            try:
                rec = ray.get(ready[0])
            except Exception as e:  # the worker process died (killed, out of memory): record it here
                first = str(e).strip().splitlines()[0] if str(e).strip() else ""
                rec = _failed_record(spec, f"worker died: {type(e).__name__}: {first}")
                rec["finished"] = time.time()
                _write_json(run_dir / RESULT_FILE, rec)
            on_done(rec)
    finally:
        if started_here:
            ray.shutdown()


def plan(manifest: Manifest, opts: BatchOptions) -> list[RunSpec]:
    specs = manifest.runs(data_roots(list(opts.data_roots), manifest))
    if opts.max_frames is not None:
        cap = opts.max_frames
        specs = [
            dataclasses.replace(
                s, sequence=dataclasses.replace(s.sequence, frames=min(s.sequence.frames or cap, cap))
            )
            for s in specs
        ]
    return specs


def run_batch(
    manifest: Manifest, opts: BatchOptions, on_done: Callable[[dict], None] | None = None
) -> BatchResult:
    """Run every incomplete run of ``manifest`` into ``opts.out``; write and return the table."""
    if opts.jobs < 1:
        raise BatchError(f"--jobs must be >= 1, got {opts.jobs}")
    out = Path(opts.out)
    (out / "runs").mkdir(parents=True, exist_ok=True)
    copy = out / "manifest.yaml"
    if manifest.source is not None and not (copy.exists() and copy.samefile(manifest.source)):
        shutil.copyfile(manifest.source, copy)
    specs = plan(manifest, opts)
    todo, reused = [], []
    for spec in specs:
        run_dir = out / "runs" / spec.run_id
        if spec.missing:
            continue
        if is_complete(run_dir, spec):
            reused.append(spec.run_id)
        else:
            todo.append((spec, run_dir))
    log.info("batch %s: %d runs, %d complete, %d to run, %d without data", manifest.name, len(specs),
             len(reused), len(todo), sum(s.missing for s in specs))  # fmt: skip
    done = on_done or (lambda rec: None)
    if todo and opts.jobs == 1 and not opts.address:
        for spec, run_dir in todo:
            done(execute_run(spec, str(run_dir)))
    elif todo:
        _run_ray(todo, opts, done)
    rows = collect_rows(out, specs)
    write_tables(out, manifest.name, rows, [s.run_id for s, _ in todo], reused)
    return BatchResult(out, rows, [s.run_id for s, _ in todo], reused)


def _row(spec: RunSpec, run_dir: Path) -> dict:
    base = {"sequence": spec.sequence.name, "config": spec.variant.name, "dataset": spec.sequence.dataset,
            "mode": spec.sequence.mode}  # fmt: skip
    if spec.missing:
        where = spec.sequence.ground_truth if spec.sequence.ground_truth else spec.sequence.path
        return {
            **base,
            "status": "skipped",
            "error": f"data not found: {where} (see --data-root, $GSSLAM_DATA)",
        }
    rec = read_result(run_dir)
    if rec is None or rec.get("fingerprint") != spec.fingerprint():
        return {**base, "status": "not run", "error": "no result for this plan entry (interrupted?)"}
    rec.pop("traceback", None)
    return {**base, **rec, "run_dir": str(run_dir)}


def collect_rows(out: Path, specs: list[RunSpec]) -> list[dict]:
    return [_row(spec, Path(out) / "runs" / spec.run_id) for spec in specs]


def write_tables(out: Path, title: str, rows: list[dict], executed: list[str], reused: list[str]) -> None:
    from gsslam.run.results import csv_text, markdown, means_by_config

    (out / "results.md").write_text(markdown(rows, title=title))
    (out / "results.csv").write_text(csv_text(rows))
    _write_json(out / "results.json", {"batch": title, "rows": rows, "means": means_by_config(rows),
                                       "executed": executed, "reused": reused})  # fmt: skip
    try:
        from gsslam.viz.batch_plot import plot_ate_bars

        plot_ate_bars(out / "ate.png", rows, title=title)
    except Exception as e:  # a plot must never lose a batch's numbers
        log.warning("ATE plot failed: %s", e)


def read_rows(path: Path) -> list[dict]:
    """The rows of a finished batch: its folder (holding results.json) or the results.json itself."""
    p = Path(path)
    p = p / "results.json" if p.is_dir() else p
    try:
        return json.loads(p.read_text())["rows"]
    except (OSError, ValueError, KeyError) as e:
        raise BatchError(f"cannot read batch results from {p}: {e}; give a batch output folder") from None
