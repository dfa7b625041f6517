"""Measuring tool (docs/results.md, "The pose-outlier check at direction reversals, session 12"), not a test.

Reads ``nearkf_probe.py`` pickles and re-poses the frames between keyframes from the SAME run (same
keyframes, same graph, same tracks) with the pose-outlier check of ``slam/poses.py::frame_poses`` off,
as it was (``motion_check`` off) and with ``motion_check`` on; prints, per run, the frames each flags with
their error against the truth as tracked and as replaced (under the all-frame alignment of the run as
written), and the all-frame ATE SE(3) of each posing.

    PYTHONPATH=. python3 tests/accuracy/outlier_split.py [--table] RUN.pkl [...]
"""

from __future__ import annotations

import json
import pickle
import sys

import numpy as np

from gsslam.eval.ate import ate_from_pairs
from gsslam.frontend.pose_outliers import find_pose_outliers
from gsslam.frontend.tracking import interpolate_poses

VARIANTS = {"off": None, "line": False, "motion": True}  # name -> motion_check (None: no check)


def posed(st: dict, motion_check: bool | None) -> tuple[dict[int, np.ndarray], list[int]]:
    kfp, ts, rel = st["keyframes"], st["ts"], st["relative"]
    poses = dict(kfp)  # as frame_poses before its outlier check (blend off)
    poses.update({f: kfp[a] @ T for f, (a, T) in rel.items() if a in kfp})
    bad = [] if motion_check is None else find_pose_outliers(poses, set(kfp), ts, motion_check=motion_check)
    tracked = {f: poses.pop(f) for f in bad}
    poses.update(interpolate_poses(poses, bad, ts))
    poses = {f: poses[f] for f in st["frames"] if f in poses}
    return poses, [(f, tracked[f]) for f in bad]


def report(path: str) -> dict:
    st = pickle.load(open(path, "rb"))
    gt_t, gt_T, ts = st["gt_t"], st["gt_T"], st["ts"]

    def gt_of(i):
        j = int(np.argmin(np.abs(gt_t - ts[i])))
        return gt_T[j] if abs(gt_t[j] - ts[i]) < 0.02 else None

    def ate(poses):
        idx = [i for i in sorted(poses) if gt_of(i) is not None]
        G = np.array([gt_of(i)[:3, 3] for i in idx])
        return ate_from_pairs(G, np.array([poses[i][:3, 3] for i in idx]), "se3")

    al = ate(st["frames"]).alignment  # the run as written
    res = {"run": path.split("/")[-1].removesuffix(".pkl").removesuffix("_back")}
    for name, mc in VARIANTS.items():
        poses, flagged = posed(st, mc)
        if name == "line":
            res["line_reproduces_run"] = all(np.allclose(poses[f], T) for f, T in st["frames"].items())
        res[name] = round(100 * ate(poses).stats.rmse, 3)

        def cm(T, f):
            return round(
                100 * float(np.linalg.norm(al.apply_positions(T[None, :3, 3])[0] - gt_of(f)[:3, 3])), 2
            )

        res[f"{name}_flagged"] = {f: (cm(T, f), cm(poses[f], f)) for f, T in flagged if gt_of(f) is not None}
    return res


def main(argv: list[str]) -> int:
    table = "--table" in argv
    if table:
        print(
            "| run | no check | as was (line) | motion_check | motion / as was "
            "| flagged as was: tracked -> replaced cm | flagged with motion_check |"
        )
        print("|---" * 7 + "|")
    for p in (a for a in argv if a != "--table"):
        r = report(p)
        if not table:
            print(json.dumps(r))
            continue
        fl = lambda d: ", ".join(f"{f}: {a:.2f} -> {b:.2f}" for f, (a, b) in d.items()) or "-"  # noqa: E731
        d = 100 * (r["motion"] / r["line"] - 1)
        cells = [r["run"], f"{r['off']:.3f}", f"{r['line']:.3f}", f"**{r['motion']:.3f}**", f"{d:+.1f} %"]
        cells += [fl(r["line_flagged"]), fl(r["motion_flagged"])]
        print("| " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
