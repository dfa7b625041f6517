"""The trajectory's camera (session 16): per run of a batch whose ground truth is the depth camera's, the ATE
of trajectory.tum (the depth camera's, the default), of trajectory_colour.tum (the colour camera's: what
every run wrote before) against the same ground truth, and of the colour camera against the colour
camera's own truth (the ground truth moved back by the true baseline).

    PYTHONPATH=. python3 tests/accuracy/trajcam_report.py OUT [--baseline 0.025]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from gsslam.eval.ate import compute_ate
from gsslam.io.trajectory import read_tum
from gsslam.types import Trajectory


def ate_cm(gt: Trajectory, path: Path, align: str) -> float:
    return 100 * compute_ate(gt, read_tum(path), align=align)[0].stats.rmse


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("out", type=Path)
    ap.add_argument("--baseline", type=float, default=0.025, help="the true depth camera centre along x (m)")
    a = ap.parse_args()
    back = np.eye(4)
    back[0, 3] = -a.baseline
    print("| run | camera (b applied mm) | ATE trajectory.tum | colour camera vs the same truth | colour vs colour truth |")
    print("|---|---|---|---|---|")
    for run in sorted((a.out / "runs").iterdir()):
        if not (run / "metrics.json").is_file():
            continue
        m = json.loads((run / "metrics.json").read_text())
        if m.get("status") != "complete":
            continue
        align = "sim3" if m["mode"] == "mono" else "se3"
        gt = read_tum(run / "groundtruth.tum")
        cam = m.get("trajectory_camera", {})
        colour = run / "trajectory_colour.tum"
        if not colour.is_file():
            colour = run / "trajectory.tum"
        b = 1000 * cam.get("T_colour_camera", np.eye(4).tolist())[0][3]
        own = ate_cm(gt, run / "trajectory.tum", align)
        as_colour = ate_cm(gt, colour, align)
        truth_colour = Trajectory(gt.timestamps, gt.poses @ back)
        print(f"| {run.name} | {cam.get('camera')} ({b:.1f}) | {own:.3f} | {as_colour:.3f} | "
              f"{ate_cm(truth_colour, colour, align):.3f} |")  # fmt: skip


if __name__ == "__main__":
    main()
