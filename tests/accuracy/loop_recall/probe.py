"""Measuring tool (docs/results.md, "Loop recall, session 6"), not a test: run a sequence in-process with
the map off and loops on, record every loop candidate with its verification verdict, the submaps'
loop records and per-keyframe ground truth (pose, depth at point-map size) in
``$LOOP_RECALL_OUT/<seq>_<tag>.pkl`` (default /tmp/loop_recall). ``replay.py`` re-verifies the
candidates offline under other gates and labels each against the ground truth.
Usage: ``PYTHONPATH=. python tests/accuracy/loop_recall/probe.py fbf --tag before [--mode rgbd] [--set loop.x=y]``."""

from __future__ import annotations

import argparse
import json
import logging
import os
import pickle
import time
from pathlib import Path

import cv2
import numpy as np

import gsslam.loop.detector as detector_mod
from gsslam.config import load_config
from gsslam.datasets.base import open_dataset
from gsslam.eval.ate import compute_ate
from gsslam.slam.pipeline import Pipeline
from gsslam.types import Trajectory

OUT = os.environ.get("LOOP_RECALL_OUT", "/tmp/loop_recall")
TEDDY = "../shared/data/rgbd_dataset_freiburg3_teddy"
FBF = dict(base="tum", pattern="fbf", pause_every=97, pause_len=15, jump_every=151, jump_len=4, seed=0)
SEQ = {  # the tracking suite's rows (gsslam/run/suites/tracking.yaml)
    "fbf": ("playback", TEDDY, FBF),  # as the batch opens it: base frames without depth are skipped
    "synth800": ("synthetic", str(Path(__file__).parent.parent / "loop_replay" / "synth800.yaml"), {}),
}


def ate_cm(gt, ts, poses):
    keys = sorted(poses)
    res, _ = compute_ate(
        gt, Trajectory(np.array([ts[k] for k in keys]), np.stack([poses[k] for k in keys])), align="sim3"
    )
    return 100 * float(res.stats.rmse)


def gt_depth_getter(seq, ds):
    if seq == "synth800":
        return lambda k: ds[k].depth
    tum = open_dataset("tum", TEDDY, with_depth=True)
    tts = np.asarray(tum.timestamps())
    base_ts = np.asarray(ds.base.timestamps())

    def get(k):
        j = int(np.argmin(np.abs(tts - base_ts[ds.source_index(k)])))
        return tum[j].depth

    return get


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("seq", choices=sorted(SEQ))
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--tag", default="")
    ap.add_argument("--mode", default="mono", choices=["mono", "rgbd"])
    a = ap.parse_args()
    os.makedirs(OUT, exist_ok=True)
    logging.basicConfig(level=logging.WARNING)
    name, path, kw = SEQ[a.seq]
    ds = open_dataset(name, path, **kw)
    cfg = load_config(None, ["mapper.enabled=false", "loop.enabled=true", *a.set], mode=a.mode)
    pipe = Pipeline(cfg, ds.intrinsics)
    cands = []
    inner = detector_mod.verify_candidate

    def recording(cand, rec_i, rec_m, cfg_, mode, rng):
        v = inner(cand, rec_i, rec_m, cfg_, mode, rng)
        cands.append(
            dict(
                i=cand.i,
                m=cand.m,
                cand=cand,
                matches=v.matches,
                inliers=v.inliers,
                why=v.why,
                T_i_m=None if v.loop is None else v.loop.T_i_m,
                X_i=None if v.loop is None else v.loop.X_i,
                X_m=None if v.loop is None else v.loop.X_m,
            )
        )
        return v

    detector_mod.verify_candidate = recording
    gt_pose = {}
    t0 = time.time()
    for k in range(len(ds)):
        f = ds[k]
        gt_pose[k] = f.T_world_cam_gt
        pipe.process(f)
    pipe.close_chain()
    ts = pipe.timestamps
    gt = ds.ground_truth()
    kf_before = pipe.keyframe_poses()
    pipe.finish()
    wall = time.time() - t0
    ch = pipe.chains[0]
    det = pipe.loop_stage._detectors[0]
    depth_of = gt_depth_getter(a.seq, ds)
    subs = []
    for rec, enc in zip(det.records(), ch.encodings):
        hs, ws = rec.depth_small.shape[1:]
        dgt = [
            cv2.resize(
                np.nan_to_num(depth_of(fi), nan=0.0).astype(np.float32),
                (ws, hs),
                interpolation=cv2.INTER_NEAREST,
            )
            for fi in rec.frame_indices
        ]
        subs.append(
            dict(
                rec=rec,
                gt_T_world_cam=[gt_pose[fi] for fi in rec.frame_indices],
                gt_depth_small=np.stack(dgt),
            )
        )
    met = pipe.loop_stage.metrics()
    row = dict(
        seq=a.seq,
        mode=a.mode,
        tag=a.tag,
        set=a.set,
        chains=len(pipe.chains),
        ate_cm=ate_cm(gt, ts, pipe.frame_poses()),
        ate_kf_cm=ate_cm(gt, ts, pipe.keyframe_poses()),
        ate_kf_before_batch_cm=ate_cm(gt, ts, kf_before),
        loops={
            k: met[k] for k in ("candidates", "detected", "accepted", "rejected", "in_graph", "unverified")
        },
        wall_s=round(wall, 1),
    )
    print(json.dumps(row))
    with open(f"{OUT}/results.jsonl", "a") as fh:
        fh.write(json.dumps(row) + "\n")
    with open(f"{OUT}/{a.seq}{'_rgbd' if a.mode == 'rgbd' else ''}_{a.tag}.pkl", "wb") as fh:
        pickle.dump(dict(row=row, cands=cands, subs=subs, loops=met["loops"]), fh)


if __name__ == "__main__":
    main()
