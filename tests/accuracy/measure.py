"""Measure accuracy at length: one run of the pipeline on a (played-back) sequence, one summary row.

    PYTHONPATH=. python tests/accuracy/measure.py SEQ --dataset playback --mode rgbd --loops on \
        --kw base=tum --kw pattern=fbf --kw misregister='{"baseline_m":0.025,"focal_scale":1.114}' \
        [--set key=value ...] [--tag NAME] [--log results.jsonl]

Prints (and appends to ``--log``) a JSON row: ATE all frames / keyframes (Sim(3) for mono, SE(3) for
RGB-D), ATE after Sim(3) alignment and its scale, ATE before the batch, RPE per frame (translation mm /
rotation deg, after the Sim(3) scale in mono), loops candidates / detected / accepted / rejected, FPS.
Not a test: a measuring tool (docs/results.md, "Accuracy at length").
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
import time
from pathlib import Path

import yaml

from gsslam.config import load_config
from gsslam.datasets.base import open_dataset
from gsslam.eval.ate import compute_ate
from gsslam.eval.rpe import compute_rpe
from gsslam.io.trajectory import read_tum
from gsslam.run.sequence import run_dataset


def summarise(ds, out: Path, metrics: dict, mode: str) -> dict:
    gt = ds.ground_truth()
    est = read_tum(out / "trajectory.tum")
    row: dict = {}
    res3, assoc = compute_ate(gt, est, align="sim3")
    res, _ = compute_ate(gt, est, align="sim3" if mode == "mono" else "se3")
    row["ate_cm"] = 100 * res.stats.rmse
    row["ate_sim3_cm"] = 100 * res3.stats.rmse
    row["sim3_scale"] = float(res3.alignment.scale)
    kf = metrics.get("ate_keyframes") or {}
    bb = metrics.get("ate_before_batch") or {}
    row["ate_kf_cm"] = 100 * kf["rmse_m"] if kf else None
    row["ate_before_batch_cm"] = 100 * bb["rmse_m"] if bb else None
    P = est.poses[assoc.est_indices].copy()
    if mode == "mono":
        P[:, :3, 3] *= res3.alignment.scale
    rpe = compute_rpe(gt.poses[assoc.gt_indices], P, 1)
    row["rpe_mm"] = 1000 * rpe.translation.rmse
    row["rpe_deg"] = rpe.rotation_deg.rmse
    lc = metrics.get("loop_closure") or {}
    for k in ("candidates", "detected", "accepted", "rejected", "in_graph"):
        row[f"loops_{k}"] = lc.get(k)
    for k in ("frames", "frames_posed", "keyframes", "submaps", "chains", "fps"):
        row[k] = metrics.get(k)
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("seq")
    ap.add_argument("--dataset", default="playback")
    ap.add_argument("--mode", default="rgbd")
    ap.add_argument("--loops", default="on")
    ap.add_argument("--kw", action="append", default=[], help="dataset kwarg key=value (value YAML)")
    ap.add_argument("--set", action="append", default=[], dest="overrides")
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--tag", default="")
    ap.add_argument("--log", default=None)
    ap.add_argument("--out", default=None)
    ap.add_argument("--from-run", default=None, help="summarise a finished run's folder instead of running")
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    kw = {}
    for s in a.kw:
        k, v = s.split("=", 1)
        kw[k] = yaml.safe_load(v)
    if a.mode == "mono" and (a.dataset == "tum" or (a.dataset == "playback" and kw.get("base", "tum") == "tum")):
        kw.setdefault("with_depth", False)
    ds = open_dataset(a.dataset, a.seq, **kw)
    overrides = ["mapper.enabled=false", f"loop.enabled={'true' if a.loops == 'on' else 'false'}", *a.overrides]
    cfg = load_config(None, overrides, mode=a.mode)
    t0 = time.time()
    if a.from_run:
        out = Path(a.from_run)
        metrics = json.loads((out / "metrics.json").read_text())
    else:
        out = Path(a.out) if a.out else Path(tempfile.mkdtemp(prefix="acc_"))
        metrics = run_dataset(ds, cfg, out, max_frames=a.max_frames).metrics
    row = {"tag": a.tag, "seq": Path(a.seq).name, "dataset": a.dataset, "kw": kw, "mode": a.mode,
           "loops": a.loops, "set": a.overrides, **summarise(ds, out, metrics, a.mode),
           "wall_s": time.time() - t0, "out": str(out)}
    line = json.dumps(row)
    print(line)
    if a.log:
        with open(a.log, "a") as f:
            f.write(line + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
