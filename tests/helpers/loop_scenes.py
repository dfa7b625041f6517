"""Synthetic revisit scenes (the ``block_room`` preset) and helpers shared by the loop tests."""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.config import LoopConfig
from gsslam.datasets.synthetic import block_room, make_submaps
from gsslam.datasets.synthetic.trajectories import outward_circle, wall_scan
from gsslam.geometry import make_T, so3_exp, transform_points
from gsslam.loop import LoopConstraint, LoopDetector

# 10 submaps of K=6 over 1.2 turns of a circle looking outward at the walls of a textured room:
# submaps 8 and 9 revisit what 0 and 1 saw. Drift: 1.5 deg of yaw per submap link (the usual
# VO failure) plus noise, i.e. about 13 deg and 0.9 m of error when the loop closes.
DRIFT = dict(drift_yaw_deg=1.5, drift_trans=0.0, drift_noise=0.003)


def run_detector(sm, mode: str, cfg: LoopConfig | None = None):
    det = LoopDetector(cfg or LoopConfig(), mode=mode)
    est = {s: T for s, T in enumerate(sm.T_world_local_est)}
    loops = {}
    for s, (enc, img) in enumerate(zip(sm.encodings, sm.images)):
        det.add_submap(s, enc, img)
        for loop in det.detect(s, est):
            loops[len(loops)] = loop
    return det, est, loops


@pytest.fixture(scope="session")
def revisit_rgbd():
    sm = make_submaps(block_room(seed=1), outward_circle(61, 1.2), mono=False, seed=0, **DRIFT)
    return sm, *run_detector(sm, "rgbd")


@pytest.fixture(scope="session")
def revisit_mono():
    sm = make_submaps(block_room(seed=1), outward_circle(61, 1.2), mono=True, seed=3, **DRIFT)
    return sm, *run_detector(sm, "mono")


@pytest.fixture(scope="session")
def corridor():
    """A sideways scan along a 20 m wall: nothing is ever seen twice."""
    room = block_room(half_extent=(11.0, 1.5, 3.0), seed=4)
    return make_submaps(room, wall_scan(61, 18.0, 2.5, 3.0), mono=False, seed=5, **DRIFT)


def gt_relative(sm, i: int, m: int) -> np.ndarray:
    return np.linalg.inv(sm.T_world_local_gt[i]) @ sm.T_world_local_gt[m]


def wrong_loop(sm, det, i=6, m=2, yaw_deg=25.0, shift=(1.0, 0.0, 0.5)):
    """A loop 6-2 (these submaps do not see the same walls) with a transform 25 deg / 1.1 m off
    the truth, on 100 of submap m's points: what perceptual aliasing would produce."""
    rec = det.record(m)
    unit = rec.median_depth / det.record(0).median_depth if det.mode == "mono" else 1.0
    T_bad = gt_relative(sm, i, m) @ make_T(
        so3_exp(np.array([0.0, np.radians(yaw_deg), 0.0])), np.array(shift) * unit
    )
    X_m = rec.points_local[:100]
    thr = 0.05 if det.mode == "rgbd" else det.cfg.inlier_threshold_rel * det.record(i).median_depth
    return LoopConstraint(i, m, transform_points(T_bad, X_m), X_m, T_bad, 0.9, 0.9, thr)


def corner_points(rng, n: int = 4000, relief: float = 0.05, wave: float = 9.0) -> np.ndarray:  # -> [n, 3]
    """Points on three orthogonal unit planes with a sinusoidal relief: a surface ICP can lock onto."""
    pts = rng.uniform(0.0, 1.0, size=(n, 3))
    face = rng.integers(0, 3, n)
    pts[np.arange(n), face] = relief * np.sin(wave * pts[np.arange(n), (face + 1) % 3])
    return pts
