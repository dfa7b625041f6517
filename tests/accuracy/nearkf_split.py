"""Measuring tool (docs/results.md, "RGB-D frames between keyframes and loops, session 11"), not a test.

Reads ``nearkf_probe.py`` pickles and prints, per run: ATE SE(3) of all frames / keyframes / frames between
(under the all-frame alignment, as the runner), the error of the frames between by their distance (in
frames) to their reference keyframe, and the ATE of the frames posed other ways from the SAME run:

- ``asis``: as written (``T_w_A T_A_f``, A the keyframe before);
- ``interp``: interpolated in time between the corrected keyframes A and B (the one after);
- ``anchorB``: ``T_w_B inv(T_A_B) T_A_f`` (B's own tracked pose against A closes the gap at B);
- ``blend``: ``asis`` and ``anchorB`` interpolated by the time fraction u of f between A and B (the
  library's ``slam/poses.py::blend_between``, ``pipeline.frame_pose_blend``);
- ``blend_motion``: the same with u the fraction of the tracked path length A -> f -> B;
- ``back``: ``T_w_B T_B_f`` (the frame tracked against the next keyframe; ``--back`` pickles);
- ``fuse``: ``asis`` and ``back`` interpolated by u; ``fuse3``: ``asis`` and the mean of ``anchorB`` and
  ``back`` interpolated by u;
- ``true_rel`` / ``true_kf``: what-ifs, the keyframe's estimate with the TRUE ``T_A_f`` / the true keyframe
  with the estimated ``T_A_f`` (as ``frame_split.py``);

and the all-frame ATE Sim(3) with its scale (``asis``).

    PYTHONPATH=. python3 tests/accuracy/nearkf_split.py [--table] RUN.pkl [...]

``--table``: one markdown row per run instead of the JSON line.
"""

from __future__ import annotations

import json
import pickle
import sys

import numpy as np

from gsslam.eval.ate import ate_from_pairs
from gsslam.frontend.pose_outliers import find_pose_outliers
from gsslam.frontend.tracking import interpolate_pose, interpolate_poses
from gsslam.geometry import invert_T
from gsslam.slam.poses import blend_between


def _neighbours(kf_sorted: list[int], f: int) -> tuple[int | None, int | None]:
    k = int(np.searchsorted(kf_sorted, f))
    a = kf_sorted[k - 1] if k > 0 else None
    b = kf_sorted[k] if k < len(kf_sorted) else None
    return a, b


def variants(st: dict, gt_of, T_est_gt: np.ndarray) -> dict[str, dict[int, np.ndarray]]:
    kfp, fr, ts, rel, trk = st["keyframes"], st["frames"], st["ts"], st["relative"], st["tracked"]
    kfs = sorted(kfp)
    names = ("asis", "interp", "anchorB", "blend", "blend_motion", "back", "fuse", "fuse3")
    names += ("true_rel", "true_kf")
    base = dict(kfp)  # as slam/poses.frame_poses before its outlier check
    base.update({f: kfp[a] @ T for f, (a, T) in rel.items() if a in kfp})
    out = {k: dict(base) for k in names}
    kf_rel = {b: trk[b] for b in kfs if b in trk}
    out["blend"].update(blend_between(kfp, rel, kf_rel, ts))
    for f, (ref, T_a_f) in rel.items():
        a, b = _neighbours(kfs, f)
        if f in fr and ref in kfp and gt_of(ref) is not None and gt_of(f) is not None:
            out["true_rel"][f] = kfp[ref] @ invert_T(gt_of(ref)) @ gt_of(f)
            out["true_kf"][f] = T_est_gt @ gt_of(ref) @ T_a_f  # the true keyframe in the estimate's frame
        if f not in fr or a != ref or b is None or b not in trk or trk[b][0] != a:
            continue
        u = (ts[f] - ts[a]) / (ts[b] - ts[a])
        P_a = kfp[a] @ T_a_f
        out["interp"][f] = interpolate_pose(kfp[a], kfp[b], u)
        P_b = kfp[b] @ invert_T(trk[b][1]) @ T_a_f
        out["anchorB"][f] = P_b
        T_b_f = invert_T(trk[b][1]) @ T_a_f
        d_a, d_b = np.linalg.norm(T_a_f[:3, 3]), np.linalg.norm(T_b_f[:3, 3])
        out["blend_motion"][f] = interpolate_pose(P_a, P_b, d_a / (d_a + d_b) if d_a + d_b > 0 else u)
        if f in st.get("back_tracked", {}) and st["back_tracked"][f][0] == b:
            P_back = kfp[b] @ st["back_tracked"][f][1]
            out["back"][f] = P_back
            out["fuse"][f] = interpolate_pose(P_a, P_back, u)
            out["fuse3"][f] = interpolate_pose(P_a, interpolate_pose(P_b, P_back, 0.5), u)
    for name, poses in out.items():  # then the outlier check of frame_poses (its defaults)
        bad = find_pose_outliers(poses, set(kfp), ts, 0.02, 3.0)
        for f in bad:
            poses.pop(f)
        poses.update(interpolate_poses(poses, bad, ts))
        out[name] = {f: poses[f] for f in fr if f in poses}
    return out


def report(path: str) -> dict:
    st = pickle.load(open(path, "rb"))
    gt_t, gt_T, ts = st["gt_t"], st["gt_T"], st["ts"]
    kfs = sorted(st["keyframes"])

    def gt_of(i):
        j = int(np.argmin(np.abs(gt_t - ts[i])))
        return gt_T[j] if abs(gt_t[j] - ts[i]) < 0.02 else None

    res = {"run": path.split("/")[-1], "loops": st["loops_metrics"].get("in_graph")}
    idx = [i for i in sorted(st["frames"]) if gt_of(i) is not None]
    G0 = np.array([gt_of(i)[:3, 3] for i in idx])
    al = ate_from_pairs(G0, np.array([st["frames"][i][:3, 3] for i in idx]), "se3")
    vs = variants(st, gt_of, invert_T(al.alignment.matrix))
    res["asis_reproduced"] = all(np.allclose(vs["asis"][f], T) for f, T in st["frames"].items())
    for name, poses in vs.items():
        idx = [i for i in sorted(poses) if gt_of(i) is not None]
        G = np.array([gt_of(i) for i in idx])
        E = np.array([poses[i] for i in idx])
        r = ate_from_pairs(G[:, :3, 3], E[:, :3, 3], "se3")
        e = np.linalg.norm(r.alignment.apply_positions(E[:, :3, 3]) - G[:, :3, 3], axis=1)
        iskf = np.array([i in st["keyframes"] for i in idx])
        rms = lambda x: round(100 * float(np.sqrt(np.mean(x**2))), 3) if len(x) else None  # noqa: E731
        res[name] = {"all": round(100 * r.stats.rmse, 3), "kf": rms(e[iskf]), "between": rms(e[~iskf])}
        if name == "asis":
            r3 = ate_from_pairs(G[:, :3, 3], E[:, :3, 3], "sim3")
            scale = round(float(r3.alignment.scale), 4)
            res["asis_sim3"] = {"all": round(100 * r3.stats.rmse, 3), "scale": scale}
        if name == "asis":  # error by distance (frames) to the reference keyframe, and to the next one
            order = {i: n for n, i in enumerate(idx)}
            by_d, by_rel = {}, {}
            for n, i in enumerate(idx):
                if iskf[n] or i not in st["relative"]:
                    continue
                a, b = _neighbours(kfs, i)
                d = order[i] - order[a] if a in order else -1
                d_b = order[b] - order[i] if b in order else -1
                by_d.setdefault(f"{d}/{d_b}", []).append(e[n])
                ref, T = st["relative"][i]
                if gt_of(ref) is not None:
                    D = invert_T(invert_T(gt_of(ref)) @ gt_of(i)) @ T
                    by_rel.setdefault(d, []).append(np.linalg.norm(D[:3, 3]))
            res["err_by_dist_prev/next"] = {k: (len(v), rms(np.array(v))) for k, v in sorted(by_d.items())}
            res["rel_err_by_dist"] = {k: (len(v), rms(np.array(v))) for k, v in sorted(by_rel.items())}
    return res


def _table_row(r: dict) -> str:
    cells = [r["run"].removesuffix(".pkl").removesuffix("_back"), str(r["loops"])]
    cells += [f"{r['asis']['all']:.3f}", f"{r['asis']['kf']:.3f}", f"{r['asis']['between']:.3f}"]
    cells += [f"{r['asis_sim3']['all']:.3f} ({r['asis_sim3']['scale']:.4f})", f"{r['true_rel']['all']:.3f}"]
    cells += [f"{r['interp']['all']:.3f}", f"{r['fuse']['all']:.3f}"]
    d = 100 * (r["blend"]["all"] / r["asis"]["all"] - 1)
    cells += [f"**{r['blend']['all']:.3f}** ({d:+.1f} %)", f"{r['blend']['between']:.3f}"]
    return "| " + " | ".join(cells) + " |"


def main(argv: list[str]) -> int:
    table = "--table" in argv
    if table:
        print(
            "| run | loops in graph | ATE all | keyframes | between | Sim(3) all (scale) | with true T_A_f "
            "| interp | fuse (back track) | blend all | blend between |"
        )
        print("|---" * 11 + "|")
    for p in (a for a in argv if a != "--table"):
        r = report(p)
        print(_table_row(r) if table else json.dumps(r))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
