"""Offline re-verification of the loop candidates recorded by ``probe.py`` (docs/results.md, "Loop recall,
session 6"), not a test. Each submap's ground-truth Sim(3) ``T_world_local`` comes from its first keyframe's
ground-truth pose and the scale of its point maps against the ground-truth depth (median ratio). A candidate
is a true loop when the ground-truth reprojection overlap of the two submaps, counting only points that both
see from directions at most 30 deg apart (what features can match), is > 0.1; a verified loop is
correct when its ``T_i_m`` moves submap m's inlier points to within 5 % of the median depth of where the
ground truth puts them (RMS) and its rotation is within 3 deg.

Usage: ``PYTHONPATH=. python tests/accuracy/loop_recall/replay.py PKL [--set loop.key=value ...] [--negatives N]``.
``--negatives N``: also verify N submap pairs with ground-truth overlap < 0.02 (the most alike by appearance
first, all view pairs by appearance): every loop verified there is a false loop (precision on real data).
"""

from __future__ import annotations

import argparse
import json
import pickle
from collections import Counter

import numpy as np

from gsslam.config import load_config
from gsslam.geometry import invert_T, make_T, so3_log, split_sim3, transform_points
from gsslam.loop.appearance import appearance_overlap
from gsslam.loop.covisibility import reprojection_overlap
from gsslam.loop.types import LoopCandidate
from gsslam.loop.verification import verify_candidate

ROT_TOL_DEG, POINT_TOL_REL, TRUE_OVERLAP, FALSE_OVERLAP = 3.0, 0.05, 0.1, 0.02
GT_VIEW_ANGLE_DEG = (
    30.0  # ground-truth overlap counts points seen from directions <= 30 deg apart (matchable)
)


def gt_world_local(sub) -> np.ndarray:
    rec = sub["rec"]
    d, g = rec.depth_small, sub["gt_depth_small"]
    ok = np.isfinite(d) & (d > 0) & (g > 0)
    s = float(np.median(g[ok] / d[ok]))
    a = next(k for k, T in enumerate(sub["gt_T_world_cam"]) if T is not None)  # first keyframe with a pose
    return sub["gt_T_world_cam"][a] @ make_T(np.eye(3), np.zeros(3), s) @ invert_T(rec.T_local_cam[a])


def loop_error(T_i_m, T_gt, X_m, median_depth):
    R, _, _ = split_sim3(invert_T(T_gt) @ T_i_m)
    rot = float(np.degrees(np.linalg.norm(so3_log(R))))
    d = transform_points(T_i_m, X_m) - transform_points(T_gt, X_m)
    return rot, float(np.sqrt((d**2).sum(1).mean())) / median_depth


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("pkl")
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--negatives", type=int, default=0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--verbose", action="store_true")
    a = ap.parse_args()
    st = pickle.load(open(a.pkl, "rb"))
    cfg = load_config(None, ["loop.enabled=true", *a.set], mode="mono").loop
    subs = st["subs"]
    M = [gt_world_local(s) for s in subs]
    rng = np.random.default_rng(a.seed)
    rows = []
    for c in st["cands"]:
        i, m = c["i"], c["m"]
        ri, rm = subs[i]["rec"], subs[m]["rec"]
        ov = reprojection_overlap(ri, M[i], rm, M[m], 0.2, GT_VIEW_ANGLE_DEG)[0]
        v = verify_candidate(c["cand"], ri, rm, cfg, "mono", rng)
        T_gt = invert_T(M[i]) @ M[m]
        row = dict(
            i=i, m=m, gt_overlap=round(ov, 3), was=c["why"], why=v.why, matches=v.matches, inliers=v.inliers
        )
        if v.loop is not None:
            rot, perr = loop_error(v.loop.T_i_m, T_gt, v.loop.X_m, ri.median_depth)
            row.update(
                rot=round(rot, 2),
                perr=round(perr, 4),
                correct=bool(rot < ROT_TOL_DEG and perr < POINT_TOL_REL),
            )
        rows.append(row)
    true = [r for r in rows if r["gt_overlap"] > TRUE_OVERLAP]
    ver = [r for r in rows if r["why"] == "verified"]
    out = dict(
        pkl=a.pkl,
        set=a.set,
        candidates=len(rows),
        true_candidates=len(true),
        verified=len(ver),
        verified_correct=sum(r["correct"] for r in ver),
        verified_of_true=sum(r["why"] == "verified" for r in true),
        was_verified=sum(r["was"] == "verified" for r in rows),
        why=dict(Counter(r["why"] for r in rows)),
    )
    if a.negatives:
        n = len(subs)
        app = {}
        neg = []
        for i in range(n):
            for m in range(i - 3):
                ov = reprojection_overlap(subs[i]["rec"], M[i], subs[m]["rec"], M[m], 0.2, GT_VIEW_ANGLE_DEG)[
                    0
                ]
                if ov < FALSE_OVERLAP:
                    A = appearance_overlap(subs[i]["rec"].appearance, subs[m]["rec"].appearance)
                    app[(i, m)] = A
                    neg.append((float(A.max()), i, m))
        neg.sort(reverse=True)
        fp = []
        for _, i, m in neg[: a.negatives]:
            A = app[(i, m)]
            flat = np.argsort(-A, axis=None)
            pairs = tuple((int(x), int(y)) for x, y in zip(*np.unravel_index(flat, A.shape)))
            cand = LoopCandidate(i, m, 0.0, float(A.max()), 1.0, pairs)
            v = verify_candidate(cand, subs[i]["rec"], subs[m]["rec"], cfg, "mono", rng)
            if v.loop is not None:
                fp.append((i, m, v.matches, v.inliers))
        out.update(
            negatives_available=len(neg),
            negatives_tried=min(len(neg), a.negatives),
            false_verified=len(fp),
            false_list=fp,
        )
    vr = [r for r in ver if "rot" in r]
    out["median_rot_deg"] = round(float(np.median([r["rot"] for r in vr])), 2) if vr else None
    out["median_perr"] = round(float(np.median([r["perr"] for r in vr])), 4) if vr else None
    out["bad_rot_gt10"] = sum(r["rot"] > 10 for r in vr)
    print(json.dumps(out))
    if a.verbose:
        for r in rows:
            print(r)


if __name__ == "__main__":
    main()
