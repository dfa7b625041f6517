"""Re-timing the depth for a known delay (session 17): per run of synthetic batches with ``depth_delay_s``
(tests/accuracy/retime_*_s17.yaml), the ATE as metrics.json has it (trajectory.tum: the depth camera, at the
depth image's time when the run was given the delay, against the truth: the depth camera at the depth image's
time, as 7-Scenes), the same poses written at the colour image's time (trajectory_colour.tum @ T_colour_depth)
against that truth, the depth camera against the truth without the delay, the colour camera against the
colour truth, RPE, Sim(3) scale, the registration applied and how many frames were re-timed.

    PYTHONPATH=. python3 tests/accuracy/retime_report_s17.py OUT [OUT ...]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).parent))
from tsync_report_s16 import ate_cm, complete_runs, truth_without_delay  # noqa: E402

from gsslam.datasets.synthetic import SyntheticDataset  # noqa: E402
from gsslam.eval.ate import compute_ate  # noqa: E402
from gsslam.io.trajectory import read_tum  # noqa: E402
from gsslam.types import Trajectory  # noqa: E402


def written_at_colour_time_cm(kw: dict, run: Path, m: dict) -> float:
    """The colour camera's poses @ T_colour_depth (the depth camera at the colour image's time) against the
    run's truth (the depth camera at the depth image's time)."""
    colour = run / "trajectory_colour.tum"
    if not colour.is_file():
        return float("nan")
    T_cd = np.asarray(m["trajectory_camera"]["T_colour_camera"])
    tr = read_tum(colour)
    at_colour = Trajectory(tr.timestamps, tr.poses @ T_cd)
    gt = SyntheticDataset(**kw).ground_truth()
    return 100 * compute_ate(gt, at_colour, align="se3")[0].stats.rmse


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("outs", type=Path, nargs="+")
    a = ap.parse_args()
    print(
        "| run | delay ms | given ms | frames | ATE cm (metrics) | written at colour time "
        "| vs truth without delay | colour vs colour truth | RPE cm / deg | Sim3 scale | k "
        "| b mm (hand-eye chi2) | re-timed | loops |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    nan = float("nan")
    for run, m, row, kw, colour in complete_runs(a.outs):
        cfg = yaml.safe_load((run / "config.yaml").read_text())
        given = 1000 * float(cfg["encoder"].get("depth_delay_s", 0.0))
        cf, lc = m.get("colour_focal") or {}, m.get("loop_closure") or {}
        rt = m.get("depth_retiming") or {}
        rpe = f"{100 * row['rpe_t_m']:.3f} / {row['rpe_r_deg']:.4f}" if row else "-"
        scale = f"{row['sim3_scale']:.4f}" if row else "-"
        no_delay = ate_cm(truth_without_delay(kw, "depth"), run / "trajectory.tum")
        colour_own = ate_cm(truth_without_delay(kw, "colour"), colour)
        reg = f"{cf.get('ratio_applied', nan):.4f} | {1000 * cf.get('baseline_m_applied', nan):.1f}"
        n_rt = rt.get("frames_retimed", 0) + rt.get("frames_not_retimed", 0)
        retimed = f"{rt['frames_retimed']}/{n_rt}" if rt else "-"
        print(
            f"| {run.name} | {1000 * float(kw.get('depth_delay_s', 0.0)):g} | {given:g} "
            f"| {m['frames_posed']} | {100 * m['ate']['rmse_m']:.3f} "
            f"| {written_at_colour_time_cm(kw, run, m):.3f} | {no_delay:.3f} "
            f"| {colour_own:.3f} | {rpe} | {scale} | {reg} ({cf.get('handeye_median_chi2', nan):.1f}) "
            f"| {retimed} | {lc.get('accepted')}/{lc.get('detected')} |"
        )


if __name__ == "__main__":
    main()
