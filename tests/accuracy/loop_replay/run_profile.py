"""Measuring tool (docs/results.md, "Loops that correct, session 9"), not a test: where the error of runner
run folders sits along the sequence. For each folder: ATE of all frames and of keyframes, SE(3) and
Sim(3) (scale), and the SE(3) error of the keyframes in ``--bins`` equal stretches of the sequence
(cm), so a loops-on folder and its loops-off twin can be read side by side; then the frames between
keyframes: their SE(3) error as run, and with their positions interpolated in time between the
surrounding keyframes (do the keyframes' corrections reach them?).

Usage: ``PYTHONPATH=. python tests/accuracy/loop_replay/run_profile.py RUN_DIR [RUN_DIR ...] [--bins 10]``.
"""
import argparse
from pathlib import Path

import numpy as np

from gsslam.eval.ate import compute_ate
from gsslam.io.trajectory import read_tum
from gsslam.types import Trajectory


def profile(run: Path, bins: int) -> str:
    gt = read_tum(run / "groundtruth.tum")
    out = [run.name]
    for name in ("trajectory.tum", "keyframes.tum"):
        est = read_tum(run / name)
        se3, assoc = compute_ate(gt, est, align="se3")
        sim3, _ = compute_ate(gt, est, align="sim3")
        out.append(f"{name.split('.')[0]}: SE(3) {100 * se3.stats.rmse:.3f} Sim(3) {100 * sim3.stats.rmse:.3f} "
                   f"scale {sim3.alignment.scale:.4f}")  # fmt: skip
        if name == "keyframes.tum":
            e = np.asarray(se3.errors) * 100
            parts = np.array_split(e, bins)
            out.append("  kf SE(3) error by stretch: " + " ".join(f"{p.mean():.2f}" for p in parts if len(p)))
    out.append(between_keyframes(gt, read_tum(run / "trajectory.tum"), read_tum(run / "keyframes.tum")))
    return "\n".join(out)


def between_keyframes(gt, tr, kf) -> str:
    """SE(3) error (cm RMS) of keyframes / other frames as run / other frames interpolated between keyframes."""
    near = np.clip(np.searchsorted(kf.timestamps, tr.timestamps), 1, len(kf.timestamps) - 1)
    dt = np.minimum(np.abs(kf.timestamps[near] - tr.timestamps), np.abs(kf.timestamps[near - 1] - tr.timestamps))
    is_kf = dt < 1e-4
    P = tr.poses.copy()
    for j, t in enumerate(tr.timestamps):
        k = np.searchsorted(kf.timestamps, t)
        if not is_kf[j] and 0 < k < len(kf.timestamps):
            w = (t - kf.timestamps[k - 1]) / (kf.timestamps[k] - kf.timestamps[k - 1])
            P[j, :3, 3] = (1 - w) * kf.poses[k - 1, :3, 3] + w * kf.poses[k, :3, 3]
    out = []
    for poses in (tr.poses, P):
        res, assoc = compute_ate(gt, Trajectory(tr.timestamps, poses), align="se3")
        e = np.full(len(tr.timestamps), np.nan)
        e[assoc.est_indices] = res.errors
        out.append((np.sqrt(np.nanmean(e[is_kf] ** 2)), np.sqrt(np.nanmean(e[~is_kf] ** 2)), 100 * res.stats.rmse))
    (k0, o0, a0), (_, o1, a1) = out
    return (f"  frames between keyframes ({(~is_kf).sum()}): SE(3) {100 * o0:.3f} (keyframes {100 * k0:.3f}); "
            f"interpolated between keyframes {100 * o1:.3f} (all frames {a0:.3f} -> {a1:.3f})")  # fmt: skip


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("runs", nargs="+")
    ap.add_argument("--bins", type=int, default=10)
    a = ap.parse_args()
    for r in a.runs:
        print(profile(Path(r), a.bins))


if __name__ == "__main__":
    main()
