"""Measuring tool (docs/results.md, "Loops that correct, session 9"), not a test: audit the loops of a run
kept by ``exp.py`` against ground truth.

(a) each loop's relative pose T_i_m against the ground-truth one (the two submaps at their best rigid
    poses; rotation / translation error), next to the error of the graph's estimate between the same
    submaps at the end of the run (every loop in, before the final batch), and the loop's weight: the
    aggregate std of its N point residuals (sigma / sqrt(N));
(b) recall: submap pairs whose keyframes see the same surface under ground truth (frustum overlap of
    submap i's keyframes at their median depth in submap m's keyframes) against the loops found;
(c) per-submap keyframe error (SE(3)-aligned to ground truth) along the sequence, before / after the batch.

Usage: ``PYTHONPATH=. python tests/accuracy/loop_replay/loop_audit.py KEPT.pkl [--off KEPT_OFF.pkl]``.
"""
import argparse
import pickle

import numpy as np

from gsslam.eval.ate import compute_ate
from gsslam.eval.submaps import best_submap_pose
from gsslam.geometry import invert_T
from gsslam.types import Trajectory

FOV = (0.61, 0.46)  # half-width tan of the teddy (Kinect) camera: 320/525, 240/525


def gt_at(st, f):
    gt, t = st["gt"], st["ts"][f]
    i = int(np.clip(np.searchsorted(gt.timestamps, t), 1, len(gt.timestamps) - 1))
    i = i if abs(gt.timestamps[i] - t) < abs(gt.timestamps[i - 1] - t) else i - 1
    return gt.poses[i]


def rot_deg(R):
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))


def gt_local(st, k):
    """Ground-truth T_world_local of submap k through its first view (T_local_cam[0])."""
    return gt_at(st, st["frame_indices"][k][0]) @ invert_T(st["T_local_cam"][k][0])


def gt_local_best(st, k):
    """Ground-truth T_world_local of submap k at its best rigid fit over all its keyframes: the pose a
    submap-level correction can at best give it (:func:`gsslam.eval.submaps.best_submap_pose`)."""
    G = np.stack([gt_at(st, f) for f in st["frame_indices"][k]])
    return best_submap_pose(st["T_local_cam"][k], G)


def rigid(T):
    T = T.copy()
    T[:3, :3] /= np.cbrt(np.linalg.det(T[:3, :3]))
    return T


def loops_table(st, sigma_m=0.05, ref=gt_local_best):
    rows = []
    for lc in st["loopc"]:
        i, m = lc["i"], lc["m"]
        G = invert_T(ref(st, i)) @ ref(st, m)
        D = invert_T(G) @ lc["T_i_m"]
        E = invert_T(G) @ (invert_T(rigid(st["S_before"][i])) @ rigid(st["S_before"][m]))
        r_gt = np.linalg.norm(lc["X_i"] - (lc["X_m"] @ G[:3, :3].T + G[:3, 3]), axis=1)
        r_fit = np.linalg.norm(lc["X_i"] - (lc["X_m"] @ lc["T_i_m"][:3, :3].T + lc["T_i_m"][:3, 3]), axis=1)
        rows.append(dict(i=i, m=m, n=len(lc["X_i"]), dt_mm=1e3 * np.linalg.norm(D[:3, 3]), dr_deg=rot_deg(D[:3, :3]),
                         est_dt_mm=1e3 * np.linalg.norm(E[:3, 3]), est_dr_deg=rot_deg(E[:3, :3]),
                         rms_gt_mm=1e3 * np.sqrt(np.mean(r_gt ** 2)), rms_fit_mm=1e3 * np.sqrt(np.mean(r_fit ** 2)),
                         agg_sigma_mm=1e3 * sigma_m / np.sqrt(len(lc["X_i"]))))  # fmt: skip
    return rows


def frustum_overlap(st, i, m, n=12):
    """Share of a grid over submap i's keyframes (at the submap's median depth) inside a keyframe of m."""
    u = np.linspace(-FOV[0], FOV[0], n)
    v = np.linspace(-FOV[1], FOV[1], n)
    uu, vv = np.meshgrid(u, v)
    z = st["enc_depth_med"][i] if "enc_depth_med" in st else 1.0
    P = np.stack([uu.ravel() * z, vv.ravel() * z, np.full(uu.size, z)], 1)
    hits, total = 0, 0
    Tm = [gt_at(st, f) for f in st["frame_indices"][m]]
    for f in st["frame_indices"][i]:
        Pw = P @ gt_at(st, f)[:3, :3].T + gt_at(st, f)[:3, 3]
        seen = np.zeros(len(P), bool)
        for T in Tm:
            Q = (Pw - T[:3, 3]) @ T[:3, :3]
            ok = Q[:, 2] > 0.1
            x, y = Q[:, 0] / np.maximum(Q[:, 2], 1e-6), Q[:, 1] / np.maximum(Q[:, 2], 1e-6)
            seen |= ok & (np.abs(x) < FOV[0]) & (np.abs(y) < FOV[1])
        hits += seen.sum()
        total += len(P)
    return hits / total


def kf_errors(st, key):
    P = st[key]
    ks = sorted(P)
    tr = Trajectory(np.array([st["ts"][k] for k in ks]), np.stack([P[k] for k in ks]))
    res, assoc = compute_ate(st["gt"], tr, align="se3")
    err = np.zeros(len(ks)) * np.nan
    err[assoc.est_indices] = res.errors if hasattr(res, "errors") else np.nan
    return ks, err, 100 * res.stats.rmse


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("pkl")
    ap.add_argument("--off", default=None)
    ap.add_argument("--skip-recent", type=int, default=2)
    a = ap.parse_args()
    st = pickle.load(open(a.pkl, "rb"))
    print("## (a) loops against ground truth (reference: each submap at its best rigid pose)")
    rows = loops_table(st)
    print("i m n | loop err mm deg | graph (i,m) at the end, before the batch: err mm deg | pts rms GT / fit mm"
          " | agg sigma mm")
    for r in rows:
        print(f"{r['i']:3d} {r['m']:3d} {r['n']:4d} | {r['dt_mm']:6.1f} {r['dr_deg']:5.2f} | {r['est_dt_mm']:6.1f} "
              f"{r['est_dr_deg']:5.2f} | {r['rms_gt_mm']:6.1f} {r['rms_fit_mm']:6.1f} | {r['agg_sigma_mm']:.2f}")  # fmt: skip
    if rows:
        for k in ("dt_mm", "dr_deg", "est_dt_mm", "est_dr_deg", "rms_gt_mm", "rms_fit_mm", "agg_sigma_mm", "n"):
            v = np.array([r[k] for r in rows])
            print(f"  {k}: median {np.median(v):.2f}  p90 {np.percentile(v, 90):.2f}  max {v.max():.2f}")
    print("## (b) recall: ground-truth overlapping submap pairs vs loops")
    ns = len(st["frame_indices"])
    found = {(r["i"], r["m"]) for r in rows}
    logged = {(e["i"], e["m"]): e for e in st["loops"].get("loops", [])}
    bins = [0.3, 0.5, 0.7, 0.9]
    counts = {b: [0, 0] for b in bins}
    per_i = {}
    for i in range(ns):
        for m in range(0, i - a.skip_recent):
            ov = frustum_overlap(st, i, m)
            for b in bins:
                if ov > b:
                    counts[b][0] += 1
                    counts[b][1] += (i, m) in found
            if ov > 0.5:
                per_i.setdefault(i, []).append((m, round(ov, 2), (i, m) in found))
    for b in bins:
        print(f"  GT overlap > {b}: {counts[b][0]} pairs, {counts[b][1]} with a loop in the graph")
    print(f"  loops in graph {len(found)}, logged (detected) {len(logged)}; submaps {ns}")
    subs_with = sum(1 for i in per_i if any(f for _, _, f in per_i[i]))
    print(f"  submaps with a GT revisit (>0.5): {len(per_i)}, with >= 1 loop: {subs_with}")
    print("## (c) keyframe error (SE(3)) per submap, cm")
    for lab, s in (("on", st), ("off", pickle.load(open(a.off, "rb")) if a.off else None)):
        if s is None:
            continue
        for key in ("kf_before", "kf_after"):
            ks, err, rm = kf_errors(s, key)
            idx = {f: j for j, f in enumerate(ks)}
            prof = [np.nanmean([err[idx[f]] for f in fi if f in idx]) * 100 for fi in s["frame_indices"]]
            print(f"  {lab} {key}: ATE {rm:.3f} | " + " ".join(f"{p:.1f}" for p in prof))


if __name__ == "__main__":
    main()
