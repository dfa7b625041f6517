"""Session 17 (retime), an instrument: the upper bound of re-timing the depth for a known delay. Runs a
manifest of synthetic rows (one sequence, ``depth_delay_s`` in its kwargs; configs with
``encoder.depth_delay_s``) with the colour camera's motion over the delay taken from the simulation's TRUTH
(``D_k = T_c(t_k)^-1 T_c(t_k + tau)``, the path the simulator interpolated) instead of the constant-velocity
extrapolation of the poses the run has tracked (:class:`gsslam.frontend.depth_retiming.DepthRetimer`).
The written trajectory (the depth camera at the depth image's time) still takes D from its own poses.
docs/results.md, "Re-timing the depth for a known delay, session 17".

    PYTHONPATH=. python3 tests/accuracy/retime_oracle_s17.py tests/accuracy/retime_room400_d16_s17.yaml OUT
    PYTHONPATH=. python3 tests/accuracy/retime_report_s17.py OUT
"""

from __future__ import annotations

import argparse
import logging
from dataclasses import replace
from pathlib import Path

import numpy as np

import gsslam.run.sequence as sequence
from gsslam.datasets.synthetic import SyntheticDataset
from gsslam.datasets.synthetic.dataset import delayed_poses
from gsslam.frontend.depth_retiming import DepthRetimer
from gsslam.run.batch import BatchOptions, run_batch
from gsslam.run.manifest import load_manifest


def true_motions(kwargs: dict) -> dict[float, np.ndarray]:
    """Colour image's time -> the colour camera's true motion over the delay (the simulation's path)."""
    mis = {**kwargs["misregister"], "ground_truth": "colour"}
    ds = SyntheticDataset(**{**kwargs, "misregister": mis, "depth_delay_s": 0.0})
    gt = ds.ground_truth()
    later = delayed_poses(gt.poses, kwargs["depth_delay_s"] * ds.fps)
    return {round(float(t), 6): np.linalg.inv(P) @ Q for t, P, Q in zip(gt.timestamps, gt.poses, later)}


class OracleRetimer(DepthRetimer):
    truth: dict[float, np.ndarray] = {}

    def _motion(self, timestamp: float) -> np.ndarray | None:
        return self.truth.get(round(float(timestamp), 6))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("manifest")
    ap.add_argument("out", type=Path)
    ap.add_argument("--config", default="retimed", help="the manifest's config to run (it gives the delay)")
    a = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    m = load_manifest(a.manifest)
    (seq,) = m.sequences
    OracleRetimer.truth = true_motions(seq.kwargs)
    sequence.DepthRetimer = OracleRetimer  # the run's velocity source replaced by the truth
    variants = tuple(v for v in m.variants if v.name == a.config)
    m = replace(m, name=m.name + "_oracle", variants=variants, source=None)
    res = run_batch(m, BatchOptions(out=a.out, jobs=1, data_roots=()))
    print((a.out / "results.md").read_text(), res.executed)


if __name__ == "__main__":
    main()
