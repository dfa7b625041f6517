"""Colour and depth taken at different times (session 16): per run of synthetic batches with
``depth_delay_s``, the ATE as metrics.json has it (trajectory.tum, the depth camera, against the ground truth:
the depth camera at the depth image's time, as 7-Scenes), the same trajectory against the depth camera at the
colour image's time (the truth without the delay: what tracking itself got wrong), the colour camera's
trajectory against the colour camera's truth, RPE, Sim(3) scale and the registration estimate (metrics.json
``colour_focal``).

    PYTHONPATH=. python3 tests/accuracy/tsync_report_s16.py OUT [OUT ...]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import yaml

from gsslam.datasets.synthetic import SyntheticDataset
from gsslam.eval.ate import compute_ate
from gsslam.io.trajectory import read_tum
from gsslam.types import Trajectory


def complete_runs(
    outs: list[Path],
):  # -> (run folder, metrics.json, the batch's row, synthetic kwargs, colour file)
    """Every complete run of the batches in ``outs``; the others printed as a table row with their status."""
    for out in outs:
        table = out / "results.json"
        rows = json.loads(table.read_text())["rows"] if table.is_file() else []
        by_run = {r["run_id"]: r for r in rows}  # RPE, Sim(3) scale: the batch's table (written at its end)
        for run in sorted((out / "runs").iterdir()):
            m = json.loads((run / "metrics.json").read_text()) if (run / "metrics.json").is_file() else {}
            if m.get("status") != "complete":
                print(f"| {run.name} | {m.get('status', 'not run')} |")
                continue
            kw = yaml.safe_load((run / "synthetic.yaml").read_text())
            colour = run / "trajectory_colour.tum"
            yield run, m, by_run.get(run.name, {}), kw, colour if colour.is_file() else run / "trajectory.tum"


def ate_cm(gt: Trajectory, path: Path) -> float:
    return 100 * compute_ate(gt, read_tum(path), align="se3")[0].stats.rmse


def truth_without_delay(kwargs: dict, camera: str) -> Trajectory:
    mis = {**kwargs["misregister"], "ground_truth": camera}
    return SyntheticDataset(**{**kwargs, "misregister": mis, "depth_delay_s": 0.0}).ground_truth()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("outs", type=Path, nargs="+")
    a = ap.parse_args()
    print(
        "| run | delay ms | frames | ATE cm (metrics) | vs depth cam at colour time | colour vs colour truth "
        "| RPE cm / deg | Sim3 scale | k | b mm (hand-eye chi2) | loops |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for run, m, row, kw, colour in complete_runs(a.outs):
        cf = m.get("colour_focal") or {}
        lc = m.get("loop_closure") or {}
        rpe = f"{100 * row['rpe_t_m']:.3f} / {row['rpe_r_deg']:.4f}" if row else "-"
        scale = f"{row['sim3_scale']:.4f}" if row else "-"
        at_colour_time = ate_cm(truth_without_delay(kw, "depth"), run / "trajectory.tum")
        colour_own = ate_cm(truth_without_delay(kw, "colour"), colour)
        nan = float("nan")
        reg = f"{cf.get('ratio_applied', nan):.4f} | {1000 * cf.get('baseline_m_applied', nan):.1f}"
        delay_ms = 1000 * float(kw.get("depth_delay_s", 0.0))
        chi2 = cf.get("handeye_median_chi2", nan)
        print(
            f"| {run.name} | {delay_ms:g} | {m['frames_posed']} | {100 * m['ate']['rmse_m']:.3f} | "
            f"{at_colour_time:.3f} | {colour_own:.3f} | {rpe} | {scale} | {reg} ({chi2:.1f}) | "
            f"{lc.get('accepted')}/{lc.get('detected')} |"
        )


if __name__ == "__main__":
    main()
