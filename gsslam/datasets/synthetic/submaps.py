"""Synthetic SING3R submaps cut from a ray-cast scene (loop tests and ``gsslam bench loop``).

Submaps follow SING3R's layout: K+1 keyframes, frame 0 shared with the previous submap, local
frame = frame 0's camera, and (mono) a random per-submap scale. Keyframes are ray-cast exactly
(grey images: the first channel), so point maps, images and poses are mutually consistent. Drift
is injected into the *estimated* submap world transforms only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gsslam.datasets.synthetic.scene import Scene
from gsslam.geometry import invert_T, make_T, so3_exp
from gsslam.types import CameraIntrinsics, SubmapEncoding


@dataclass
class SyntheticSubmaps:
    encodings: list[SubmapEncoding]
    images: list[np.ndarray]  # per submap [K+1, h, w]
    T_world_local_gt: list[np.ndarray]  # Sim(3)
    T_world_local_est: list[np.ndarray]  # with drift
    T_world_cam_gt: np.ndarray  # [N, 4, 4] all keyframes


def make_submaps(
    scene: Scene,
    T_world_cam: np.ndarray,  # [N, 4, 4] keyframe poses, N = n_submaps * K + 1
    K_frames: int = 6,
    width: int = 160,
    height: int = 120,
    mono: bool = False,
    drift_yaw_deg: float = 0.0,
    drift_trans: float = 0.0,
    drift_noise: float = 0.0,
    depth_noise: float = 0.005,
    seed: int = 0,
) -> SyntheticSubmaps:
    """Cut keyframes into overlapping submaps, ray-cast them, and build drifted estimates.

    Drift per submap link: a yaw of ``drift_yaw_deg`` (systematic, the dominant VO failure), a
    translation ``drift_trans`` along the camera's x, and Gaussian noise of std ``drift_noise``
    (radians / metres); mono submaps also get a log-scale drift of ``drift_noise``.
    """
    rng = np.random.default_rng(seed)
    intr = CameraIntrinsics(
        fx=0.75 * width, fy=0.75 * width, cx=(width - 1) / 2, cy=(height - 1) / 2, width=width, height=height
    )
    K = intr.K
    n_sub = (len(T_world_cam) - 1) // K_frames
    encs, imgs, gt, est = [], [], [], []
    cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for s in range(n_sub):
        idx = list(range(s * K_frames, s * K_frames + K_frames + 1))
        scale = float(np.exp(rng.uniform(-0.5, 0.5))) if mono else 1.0  # world units per local unit
        T0 = T_world_cam[idx[0]]
        T_wl = T0.copy()
        T_wl[:3, :3] *= scale
        pts, ims, T_lc = [], [], []
        for f in idx:
            if f not in cache:
                img, z = scene.cast(T_world_cam[f], intr)
                cache[f] = (img[..., 0], z)
            g, z = cache[f]
            z_noisy = z * (1.0 + depth_noise * rng.standard_normal(z.shape))
            u, v = np.meshgrid(np.arange(width), np.arange(height))
            P = np.stack([(u - K[0, 2]) / K[0, 0] * z_noisy, (v - K[1, 2]) / K[1, 1] * z_noisy, z_noisy], -1)
            pts.append(P / scale)
            ims.append(np.clip(g + 0.01 * rng.standard_normal(g.shape), 0, 1).astype(np.float32))
            T = invert_T(T0) @ T_world_cam[f]
            T[:3, 3] /= scale
            T_lc.append(T)
        encs.append(
            SubmapEncoding(
                frame_indices=idx,
                T_local_cam=np.stack(T_lc),
                points_cam=np.stack(pts).astype(np.float32),
                confidence=np.ones((len(idx), height, width), np.float32),
                intrinsics=intr,
            )
        )
        imgs.append(np.stack(ims))
        gt.append(T_wl)
        if s == 0:
            est.append(T_wl.copy())
        else:
            rel = invert_T(gt[s - 1]) @ T_wl
            w = np.array([0.0, np.radians(drift_yaw_deg), 0.0]) + drift_noise * rng.standard_normal(3)
            t = np.array([drift_trans, 0.0, 0.0]) + drift_noise * rng.standard_normal(3)
            ds = float(np.exp(drift_noise * rng.standard_normal())) if mono else 1.0
            est.append(est[-1] @ rel @ make_T(so3_exp(w), t / scale, ds))
    return SyntheticSubmaps(encs, imgs, gt, est, T_world_cam[: n_sub * K_frames + 1])
