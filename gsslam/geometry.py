"""Rigid and similarity transforms, rotations, projection: pure numpy.

``T_a_b`` maps points from frame b to frame a. A Sim(3) is stored as a 4x4 matrix
``[[s R, t], [0, 1]]``. Quaternions are (qx, qy, qz, qw) unless a name says otherwise.
"""

from __future__ import annotations

import numpy as np


def skew(v: np.ndarray) -> np.ndarray:  # v [3] -> [3, 3]
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def so3_exp(w: np.ndarray) -> np.ndarray:  # w [3] -> R [3, 3]
    theta = float(np.linalg.norm(w))
    W = skew(w)
    if theta < 1e-10:
        return np.eye(3) + W + 0.5 * W @ W
    return np.eye(3) + np.sin(theta) / theta * W + (1 - np.cos(theta)) / theta**2 * W @ W


def so3_log(R: np.ndarray) -> np.ndarray:  # R [3, 3] -> w [3]
    cos = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    theta = float(np.arccos(cos))
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if theta < 1e-8:
        return 0.5 * v
    if np.pi - theta < 1e-5:
        # near pi: axis from the symmetric part
        A = (R + np.eye(3)) / 2.0
        axis = A[:, int(np.argmax(np.diag(A)))]
        axis = axis / np.linalg.norm(axis)
        return theta * axis
    return theta / (2.0 * np.sin(theta)) * v


def quat_to_rot(q_xyzw: np.ndarray) -> np.ndarray:  # [..., 4] -> [..., 3, 3]
    q = np.asarray(q_xyzw, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - z * w),
            2 * (x * z + y * w),
            2 * (x * y + z * w),
            1 - 2 * (x * x + z * z),
            2 * (y * z - x * w),
            2 * (x * z - y * w),
            2 * (y * z + x * w),
            1 - 2 * (x * x + y * y),
        ],
        axis=-1,
    )
    return R.reshape(q.shape[:-1] + (3, 3))


def rot_to_quat(R: np.ndarray) -> np.ndarray:  # [..., 3, 3] -> [..., 4] (qx, qy, qz, qw), qw >= 0
    R = np.asarray(R, dtype=np.float64)
    flat = R.reshape(-1, 3, 3)
    out = np.empty((flat.shape[0], 4))
    for i, m in enumerate(flat):
        tr = np.trace(m)
        if tr > 0:
            s = np.sqrt(tr + 1.0) * 2
            w, x, y, z = 0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s
        elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
            s = np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
            w, x, y, z = (m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s
        elif m[1, 1] > m[2, 2]:
            s = np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
            w, x, y, z = (m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s
        else:
            s = np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
            w, x, y, z = (m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s
        q = np.array([x, y, z, w])
        q /= np.linalg.norm(q)
        out[i] = q if q[3] >= 0 else -q
    return out.reshape(R.shape[:-2] + (4,))


def interpolate_pose(a: np.ndarray, b: np.ndarray, u: float) -> np.ndarray:  # [4, 4] x2 -> [4, 4]
    """The pose a fraction ``u`` of the way from ``a`` to ``b`` (geodesic rotation, linear translation)."""
    T = np.eye(4)
    T[:3, :3] = a[:3, :3] @ so3_exp(u * so3_log(a[:3, :3].T @ b[:3, :3]))
    T[:3, 3] = (1.0 - u) * a[:3, 3] + u * b[:3, 3]
    return T


def make_T(R: np.ndarray, t: np.ndarray, s: float = 1.0) -> np.ndarray:  # -> [4, 4]
    T = np.eye(4)
    T[:3, :3] = s * np.asarray(R)
    T[:3, 3] = np.asarray(t).reshape(3)
    return T


def sim3_scale(T: np.ndarray) -> float:
    """Scale of a Sim(3) matrix (1 for SE(3))."""
    return float(np.cbrt(np.linalg.det(T[:3, :3])))


def split_sim3(T: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """``T -> (R [3,3], t [3], s)``."""
    s = sim3_scale(T)
    return T[:3, :3] / s, T[:3, 3].copy(), s


def compose_rigid(S_a_b: np.ndarray, T_b_c: np.ndarray) -> np.ndarray:  # [4, 4], [4, 4] -> [4, 4]
    """Rigid ``T_a_c`` of a rigid (or Sim(3)) pose ``T_b_c`` seen through the Sim(3) ``S_a_b``: the
    rotation without the scale, the translation in frame-a units (rigid ``S_a_b``: ``S_a_b @ T_b_c``)."""
    T = np.asarray(S_a_b, dtype=np.float64) @ np.asarray(T_b_c, dtype=np.float64)
    T[:3, :3] /= sim3_scale(T)
    return T


def invert_T(T: np.ndarray) -> np.ndarray:
    """Inverse of an SE(3) or Sim(3) 4x4 matrix (batched over leading dims)."""
    T = np.asarray(T, dtype=np.float64)
    if T.ndim == 2:
        R, t, s = split_sim3(T)
        Ti = np.eye(4)
        Ti[:3, :3] = R.T / s
        Ti[:3, 3] = -(R.T @ t) / s
        return Ti
    return np.stack([invert_T(x) for x in T])


def transform_points(T: np.ndarray, X: np.ndarray) -> np.ndarray:  # T [4,4], X [N,3] -> [N,3]
    return X @ T[:3, :3].T + T[:3, 3]


def project(K: np.ndarray, X_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pinhole projection. ``X_cam`` [N, 3] -> (uv [N, 2], z [N])."""
    z = X_cam[:, 2]
    zs = np.where(np.abs(z) < 1e-12, 1e-12, z)
    u = K[0, 0] * X_cam[:, 0] / zs + K[0, 2]
    v = K[1, 1] * X_cam[:, 1] / zs + K[1, 2]
    return np.stack([u, v], axis=1), z


def pixel_grid(width: int, height: int) -> np.ndarray:  # -> [H, W, 2] (u, v) float64
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    return np.stack([u, v], axis=-1)


def backproject(K: np.ndarray, uv: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Lift pixels ``uv`` [N, 2] with ``depth`` [N] (z, metres) to camera points [N, 3]."""
    x = (uv[:, 0] - K[0, 2]) / K[0, 0]
    y = (uv[:, 1] - K[1, 2]) / K[1, 1]
    return np.stack([x * depth, y * depth, depth], axis=1)


def depth_to_points(K: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Point map of a depth image: ``depth`` [H, W] -> [H, W, 3] camera points (NaN where invalid)."""
    h, w = depth.shape
    uv = pixel_grid(w, h).reshape(-1, 2)
    return backproject(K, uv, depth.reshape(-1).astype(np.float64)).reshape(h, w, 3)


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool) -> np.ndarray:
    """Least-squares ``T`` (Sim(3) if ``with_scale``) with ``dst ~ T * src``; src, dst [N, 3].

    Umeyama (1991), "Least-squares estimation of transformation parameters between two point
    patterns". Returns the 4x4 matrix.
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise ValueError(f"umeyama needs two [N, 3] arrays of equal shape, got {src.shape}, {dst.shape}")
    if len(src) < 3:
        raise ValueError(f"umeyama needs at least 3 point pairs, got {len(src)}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1
    R = U @ S @ Vt
    s = 1.0
    if with_scale:
        var_s = (xs**2).sum() / len(src)
        s = float(np.trace(np.diag(D) @ S) / var_s)
    t = mu_d - s * R @ mu_s
    return make_T(R, t, s)
