"""A synthetic SING3R-style submap chain with known truth: a camera on a circle inside a textured cylinder.

Each submap i has its own (unknown) unit ``sigma_i`` and an internal scale drift: frame j of the
submap is expressed in units ``sigma_i (1 + eps_i)^(j / K)``, so chaining through the shared frame
accumulates ~``eps`` of scale error per submap. Local rotations carry small noise. Point maps are
ray-cast against the ``cylinder`` preset, so a frame seen again after the loop has the same point map.
"""

from __future__ import annotations

import numpy as np

from gsslam.datasets.synthetic import cylinder
from gsslam.datasets.synthetic.trajectories import outward_circle
from gsslam.geometry import so3_exp
from gsslam.types import CameraIntrinsics, SubmapEncoding

INTR = CameraIntrinsics(fx=20.0, fy=20.0, cx=7.5, cy=5.5, width=16, height=12)
WALL_RADIUS = 10.0
_WALL = cylinder(WALL_RADIUS)


def true_pose(f: int, n_frames: int, radius: float = 5.0) -> np.ndarray:
    """T_world_cam of frame ``f`` on a circle (y is up/down), looking outward a little ahead
    (0.5 rad); frame n_frames == frame 0."""
    return outward_circle(2, turns=-f / n_frames, radius=radius, yaw_offset=-0.5, bob=0.0, start=np.pi / 2)[
        -1
    ]


def point_map(T_wc: np.ndarray) -> np.ndarray:
    """[h, w, 3] camera points where the pixel rays hit the cylinder wall."""
    return _WALL.points(T_wc, INTR)


def make_chain(
    n_submaps: int = 50, K: int = 6, drift: float = 0.02, rot_noise_deg: float = 0.1, seed: int = 0
):
    """-> (encodings, truth {frame: T_world_cam}); the last submap's last frame revisits frame 0."""
    rng = np.random.default_rng(seed)
    n_frames = n_submaps * K
    truth = {f: true_pose(f, n_frames) for f in range(n_frames + 1)}
    encs = []
    for i in range(n_submaps):
        frames = list(range(i * K, i * K + K + 1))
        sigma = float(np.exp(rng.uniform(-0.5, 0.5)))
        eps = drift * (1 + 0.25 * rng.standard_normal())
        T0_inv = np.linalg.inv(truth[frames[0]])
        T_local = np.empty((K + 1, 4, 4))
        pts = np.empty((K + 1, INTR.height, INTR.width, 3))
        for j, f in enumerate(frames):
            unit = sigma * (1 + eps) ** (j / K)
            T = T0_inv @ truth[f]
            if j > 0:
                T[:3, :3] = T[:3, :3] @ so3_exp(rng.normal(scale=np.deg2rad(rot_noise_deg), size=3))
            T[:3, 3] /= unit
            T_local[j] = T
            pts[j] = point_map(truth[f]) / unit
        conf = np.ones(pts.shape[:3])
        encs.append(SubmapEncoding(frames, T_local, pts, conf, INTR, meta={"unit": sigma}))
    return encs, truth


def ate(est: dict[int, np.ndarray], truth: dict[int, np.ndarray]) -> float:
    """RMSE of positions after Sim(3) Umeyama alignment."""
    from gsslam.geometry import umeyama

    frames = sorted(est)
    P = np.array([est[f][:3, 3] for f in frames])
    G = np.array([truth[f][:3, 3] for f in frames])
    T = umeyama(P, G, with_scale=True)
    return float(np.sqrt(((P @ T[:3, :3].T + T[:3, 3] - G) ** 2).sum(1).mean()))


def loop_points(encs, i: int, j: int, m: int, jm: int, step: int = 3):
    """Points of the same pixels of frame j of submap i and frame jm of submap m, in their local frames."""
    a = encs[i].points_cam[j][::step, ::step].reshape(-1, 3)
    b = encs[m].points_cam[jm][::step, ::step].reshape(-1, 3)
    Ta, Tb = encs[i].T_local_cam[j], encs[m].T_local_cam[jm]
    return a @ Ta[:3, :3].T + Ta[:3, 3], b @ Tb[:3, :3].T + Tb[:3, 3]
