"""Synthetic submaps for tests and ``gsslam bench loop``: a ray-cast textured room.

The scene is an axis-aligned box whose six walls carry a random block texture (one random grey
value per ``cell`` x ``cell`` square: plenty of corners for ORB, no repetition). Keyframes are
ray-cast exactly: each pixel's depth is the distance to the first wall along its ray, so point
maps, images and poses are mutually consistent. Submaps follow SING3R's layout: K+1 keyframes,
frame 0 shared with the previous submap, local frame = frame 0's camera, and (mono) a random
per-submap scale. Drift is injected into the *estimated* submap world transforms only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gsslam.geometry import invert_T, make_T, so3_exp
from gsslam.types import CameraIntrinsics, SubmapEncoding


@dataclass
class TexturedRoom:
    half_extent: np.ndarray  # [3] box half sizes (x, y, z), metres; y points down
    cell: float
    textures: list[np.ndarray]  # per wall [n, n] grey values

    @staticmethod
    def random(half_extent=(4.0, 1.5, 4.0), cell: float = 0.2, seed: int = 0) -> TexturedRoom:
        rng = np.random.default_rng(seed)
        he = np.asarray(half_extent, dtype=np.float64)
        n = int(np.ceil(2 * he.max() / cell)) + 2
        tex = [rng.uniform(0.05, 0.95, size=(n, n)) for _ in range(6)]
        return TexturedRoom(he, cell, tex)

    def cast(self, K: np.ndarray, T_world_cam: np.ndarray, w: int, h: int) -> tuple[np.ndarray, np.ndarray]:
        """Ray-cast one view: (gray [h, w] float32, z-depth [h, w] float64)."""
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        d_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1).reshape(
            -1, 3
        )
        R, o = T_world_cam[:3, :3], T_world_cam[:3, 3]
        d = d_cam @ R.T  # [P, 3], z_cam = 1 so the ray parameter t is the z-depth
        with np.errstate(divide="ignore", invalid="ignore"):
            t_pos = (self.half_extent - o) / d
            t_neg = (-self.half_extent - o) / d
        t_all = np.concatenate([t_pos, t_neg], axis=1)  # [P, 6]: walls +x +y +z -x -y -z
        t_all = np.where(t_all > 1e-9, t_all, np.inf)
        wall = np.argmin(t_all, axis=1)
        t = t_all[np.arange(len(wall)), wall]
        p = o + t[:, None] * d
        gray = np.empty(len(wall))
        for wi in range(6):
            sel = wall == wi
            a, b = [ax for ax in range(3) if ax != wi % 3]
            ia = np.floor((p[sel, a] + self.half_extent[a]) / self.cell).astype(int)
            ib = np.floor((p[sel, b] + self.half_extent[b]) / self.cell).astype(int)
            tex = self.textures[wi]
            gray[sel] = tex[np.clip(ia, 0, len(tex) - 1), np.clip(ib, 0, len(tex) - 1)]
        return gray.reshape(h, w).astype(np.float32), t.reshape(h, w)


def look_pose(position: np.ndarray, yaw: float, pitch: float = 0.0) -> np.ndarray:
    """``T_world_cam`` of a camera at ``position`` looking along yaw (about -y, world up = -y)."""
    R = so3_exp(np.array([0.0, yaw, 0.0])) @ so3_exp(np.array([pitch, 0.0, 0.0]))
    return make_T(R, position)


def circle_trajectory(
    n_keyframes: int, turns: float, radius: float = 1.2, outward: float = 0.0
) -> np.ndarray:
    """[N, 4, 4] poses on a horizontal circle looking outward (+ ``outward`` yaw offset)."""
    th = np.linspace(0.0, 2 * np.pi * turns, n_keyframes)
    poses = [
        look_pose(np.array([radius * np.sin(a), 0.1 * np.sin(3 * a), radius * np.cos(a)]), a + outward)
        for a in th
    ]
    return np.stack(poses)


def line_trajectory(n_keyframes: int, length: float, depth_to_wall: float, wall_z: float) -> np.ndarray:
    """[N, 4, 4] a sideways scan along x, looking at the +z wall from ``depth_to_wall``."""
    xs = np.linspace(-0.5 * length, 0.5 * length, n_keyframes)
    return np.stack([look_pose(np.array([x, 0.0, wall_z - depth_to_wall]), 0.0) for x in xs])


@dataclass
class SyntheticSubmaps:
    encodings: list[SubmapEncoding]
    images: list[np.ndarray]  # per submap [K+1, h, w]
    T_world_local_gt: list[np.ndarray]  # Sim(3)
    T_world_local_est: list[np.ndarray]  # with drift
    T_world_cam_gt: np.ndarray  # [N, 4, 4] all keyframes


def make_submaps(
    room: TexturedRoom,
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
                cache[f] = room.cast(K, T_world_cam[f], width, height)
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
