"""Measuring tool (docs/results.md, "Loops that correct, session 9"), not a test: where the error of runner
run folders sits along the sequence. For each folder: ATE of all frames and of keyframes, SE(3) and
Sim(3) (scale), and the SE(3) error of the keyframes in ``--bins`` equal stretches of the sequence
(cm), so a loops-on folder and its loops-off twin can be read side by side.

Usage: ``PYTHONPATH=. python tests/accuracy/loop_replay/run_profile.py RUN_DIR [RUN_DIR ...] [--bins 10]``.
"""
import argparse
from pathlib import Path

import numpy as np

from gsslam.eval.ate import compute_ate
from gsslam.io.trajectory import read_tum


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
    return "\n".join(out)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("runs", nargs="+")
    ap.add_argument("--bins", type=int, default=10)
    a = ap.parse_args()
    for r in a.runs:
        print(profile(Path(r), a.bins))


if __name__ == "__main__":
    main()
