"""A hand-held room scan for the synthetic ``room``: a sideways walk that pans and tilts (not an orbit).

The optical axes of an orbit (or of an outward circle) all meet in one point, the critical motion of
focal self-calibration (gsslam/frontend/mono_focal.py); here the camera walks 1.6 m along x in front of
the ``z = 3`` wall while its yaw and pitch swing at other periods, so the axes do not meet.
"""

from __future__ import annotations

import numpy as np

from gsslam.datasets.synthetic.trajectories import yaw_pose


def room_scan(n: int, length_m: float = 1.6) -> np.ndarray:  # -> T_world_cam [n, 4, 4]
    k = np.arange(n, dtype=np.float64)
    x = -0.5 * length_m + length_m * k / 200.0  # 8 mm per frame at the default length
    y = 0.1 * np.sin(2 * np.pi * k / 50.0)
    z = -0.5 + 0.3 * np.sin(2 * np.pi * k / 80.0)
    yaw = 0.4 * np.sin(2 * np.pi * k / 60.0)
    pitch = 0.15 * np.sin(2 * np.pi * k / 45.0)
    return np.stack([yaw_pose(np.array([x[i], y[i], z[i]]), yaw[i], pitch[i]) for i in range(n)])
