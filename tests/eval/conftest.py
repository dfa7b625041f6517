"""Helpers for the evaluation tests: random similarity transforms and perturbed trajectories."""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.geometry import make_T, so3_exp
from gsslam.types import Trajectory


def random_sim3(rng: np.random.Generator, scale: float) -> np.ndarray:  # -> [4, 4]
    return make_T(so3_exp(rng.normal(size=3)), rng.normal(size=3) * 2.0, scale)


def transform_trajectory(S: np.ndarray, poses: np.ndarray) -> np.ndarray:  # S [4,4], poses [N,4,4]
    """``S * T_i`` for a Sim(3) ``S`` with the rotation kept rigid (the camera moves, it is not scaled)."""
    s = np.cbrt(np.linalg.det(S[:3, :3]))
    R = S[:3, :3] / s
    out = poses.copy()
    out[:, :3, :3] = R @ poses[:, :3, :3]
    out[:, :3, 3] = s * poses[:, :3, 3] @ R.T + S[:3, 3]
    return out


def perturb(
    gt: Trajectory,
    rng: np.random.Generator,
    scale: float = 1.0,
    trans_noise: float = 0.01,
    rot_noise: float = 0.005,
    time_jitter: float = 0.004,
    every: int = 1,
) -> Trajectory:
    """A noisy estimate of ``gt``: Sim(3)-transformed, noisy poses, jittered timestamps, subsampled."""
    poses = transform_trajectory(random_sim3(rng, scale), gt.poses)
    poses[:, :3, 3] += rng.normal(scale=trans_noise, size=(len(gt), 3))
    for T in poses:
        T[:3, :3] = T[:3, :3] @ so3_exp(rng.normal(scale=rot_noise, size=3))
    stamps = gt.timestamps + rng.uniform(-time_jitter, time_jitter, len(gt))
    keep = np.arange(0, len(gt), every)
    # jitter may swap stamps closer than itself (teddy's GT has rows 0.5 us apart): keep time order,
    # which evaluate() requires
    keep = keep[np.argsort(stamps[keep], kind="stable")]
    return Trajectory(stamps[keep], poses[keep])


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)
