"""Measuring tool (docs/results.md, "The pose-outlier check at direction reversals, session 12"), not a test.

Runs one row of the tracking suite through ``gsslam batch`` in process (the runner's path, one run) and,
where the runner reads the frame poses, poses the frames once without the pose-outlier check and then
applies the check as it was (``pose_outlier_motion_check`` off) and with the motion check to the SAME poses
(mono re-solves its pending frames' PnP at every read, so this keeps one PnP for both). The runner writes
the variant its config asks for; this prints the ATE (Sim(3) in mono, SE(3) in RGB-D) of both and the
frames each flags.

    PYTHONPATH=. python3 tests/accuracy/outlier_mono_split.py ROW MODE [--seed N] [--set k=v ...] --out DIR
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

import gsslam.slam.poses as poses_mod
from gsslam.eval.ate import ate_from_pairs
from gsslam.frontend.pose_outliers import find_pose_outliers
from gsslam.frontend.tracking import interpolate_poses

SUITE = Path(__file__).parents[2] / "gsslam/run/suites/tracking.yaml"
CAPTURE: list = []


def _split(orig):
    def frame_poses(p):
        pc = p.cfg.pipeline
        cfg = p.cfg
        p.cfg = replace(cfg, pipeline=replace(pc, pose_outlier_max_dev_m=0.0))
        try:
            raw, _ = orig(p)
        finally:
            p.cfg = cfg
        kfs = set(poses_mod.keyframe_poses(p))
        variants = {}
        for mc in (False, True):
            dev = (pc.pose_outlier_max_dev_m, pc.pose_outlier_max_dev_deg)
            bad = find_pose_outliers(raw, kfs, p.timestamps, *dev, motion_check=mc)
            v = {f: T for f, T in raw.items() if f not in bad}
            v.update(interpolate_poses(v, bad, p.timestamps))
            variants[mc] = (dict(sorted(v.items())), bad)
        CAPTURE.append((variants, dict(p.timestamps)))
        out, bad = variants[pc.pose_outlier_motion_check]
        return out, (len(bad) if pc.pose_outlier_max_dev_m > 0 else None)

    return frame_poses


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("row")
    ap.add_argument("mode")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--out", required=True)
    ap.add_argument("--data-root", default="/work/shared/data")
    ap.add_argument("--max-frames", type=int, default=None)
    a = ap.parse_args()
    row = next(r for r in yaml.safe_load(SUITE.read_text())["sequences"] if r["name"] == a.row)
    row = {**row, "mode": a.mode}
    tag = f"{a.row}_{a.mode}_s{a.seed}" + "".join("_" + s.replace("=", "-") for s in a.set)
    out = Path(a.out) / tag
    manifest = {"name": tag, "defaults": {"set": ["mapper.enabled=false", f"seed={a.seed}", *a.set]},
                "sequences": [row], "configs": [{"name": "c", "set": []}]}  # fmt: skip
    out.mkdir(parents=True, exist_ok=True)
    (out / "manifest.yaml").write_text(yaml.safe_dump(manifest, sort_keys=False))
    poses_mod.frame_poses = _split(poses_mod.frame_poses)
    from gsslam.cli import app

    try:
        args = ["batch", str(out / "manifest.yaml"), "--jobs", "1", "--data-root", a.data_root]
        args += ["--out", str(out / "b")] + (["--max-frames", str(a.max_frames)] if a.max_frames else [])
        app(args, standalone_mode=False)
    except SystemExit:
        pass
    from gsslam.datasets.base import open_dataset

    kw = dict(row.get("kwargs") or {})
    if row.get("path") is None:
        path = out / f"{a.row}.yaml"
        path.write_text(yaml.safe_dump(kw, sort_keys=False))
        kw = {}
    else:
        path = str(Path(a.data_root) / row["path"])
    gt = open_dataset(row["dataset"], path, **kw).ground_truth()
    gt_t, gt_T = np.asarray(gt.timestamps), np.asarray(gt.poses)
    variants, ts = CAPTURE[-1]
    res = {"run": tag}
    align = "sim3" if a.mode == "mono" else "se3"
    for mc, (poses, bad) in variants.items():
        idx, G, E = [], [], []
        for f, T in poses.items():
            j = int(np.argmin(np.abs(gt_t - ts[f])))
            if abs(gt_t[j] - ts[f]) < 0.02:
                idx.append(f)
                G.append(gt_T[j][:3, 3])
                E.append(T[:3, 3])
        r = ate_from_pairs(np.array(G), np.array(E), align)
        res["motion" if mc else "line"] = {"ate_cm": round(100 * r.stats.rmse, 3), "flagged": bad}
    m = next((out / "b").rglob("metrics.json"), None)
    if m is not None:
        res["runner_ate_cm"] = round(100 * json.loads(m.read_text())["ate"]["rmse_m"], 3)
    print(json.dumps(res))
    with open(Path(a.out) / "results.jsonl", "a") as fh:
        fh.write(json.dumps(res) + "\n")


main()
