"""Shared helpers: read Pose3 / Similarity3 values as (R, t, s), point-action Jacobians, input checks.

A transform ``T`` acts on points as ``x -> s R x + t`` (``s = 1`` for Pose3). For a gtsam
``Similarity3`` (which stores ``x -> s (R x + t_g)``) this ``t`` is ``s * t_g``.

Both groups are perturbed on the RIGHT, in GTSAM's chart: ``T' = T * Expmap(xi)`` with
``xi = (omega [3], u [3])`` for Pose3 and ``xi = (omega [3], u [3], lambda)`` for Similarity3
(rotation first, then translation, then log-scale). To first order ``Expmap(xi)`` maps
``x -> x + omega x x + u + lambda x``, so ``R' = R (I + [omega]x)``, ``t' = t + s R u`` and
``s' = s (1 + lambda)``.
"""

from __future__ import annotations

import gtsam
import numpy as np

from .errors import FactorInputError

GROUPS = ("pose3", "sim3")


def group_dim(group: str) -> int:
    check_group(group)
    return 7 if group == "sim3" else 6


def check_group(group: str) -> None:
    if group not in GROUPS:
        raise FactorInputError(f"group must be one of {GROUPS}, got {group!r}")


def read_transform(values: gtsam.Values, key: int, group: str) -> tuple[np.ndarray, np.ndarray, float]:
    """``values[key]`` -> ``(R [3, 3], t [3], s)`` with ``x -> s R x + t``."""
    if group == "sim3":
        S = values.atSimilarity3(key)
        s = float(S.scale())
        return S.rotation().matrix(), s * np.asarray(S.translation()), s
    P = values.atPose3(key)
    return P.rotation().matrix(), np.asarray(P.translation()), 1.0


def to_gtsam(T: np.ndarray, group: str):  # T [4, 4] ``[[s R, t], [0, 1]]``
    """A 4x4 matrix as a gtsam value of ``group`` (for Pose3 the scale must be 1)."""
    T = np.asarray(T, dtype=np.float64)
    s = float(np.cbrt(np.linalg.det(T[:3, :3])))
    R = T[:3, :3] / s
    U, _, Vt = np.linalg.svd(R)
    R = U @ Vt
    if group == "sim3":
        return gtsam.Similarity3(gtsam.Rot3(R), T[:3, 3] / s, s)
    if abs(s - 1.0) > 1e-6:
        raise FactorInputError(f"a Pose3 needs a rigid transform, got scale {s}")
    return gtsam.Pose3(gtsam.Rot3(R), T[:3, 3])


def to_matrix(value) -> np.ndarray:  # -> [4, 4] ``[[s R, t], [0, 1]]``
    """A gtsam Pose3 / Similarity3 as our 4x4 matrix."""
    if isinstance(value, gtsam.Similarity3):
        s = float(value.scale())
        T = np.eye(4)
        T[:3, :3] = s * value.rotation().matrix()
        T[:3, 3] = s * np.asarray(value.translation())
        return T
    return np.asarray(value.matrix(), dtype=np.float64)


def skew_batch(x: np.ndarray) -> np.ndarray:  # x [N, 3] -> [N, 3, 3]
    out = np.zeros(x.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -x[..., 2], x[..., 1]
    out[..., 1, 0], out[..., 1, 2] = x[..., 2], -x[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -x[..., 1], x[..., 0]
    return out


def action_jacobian(R: np.ndarray, s: float, x: np.ndarray, group: str) -> np.ndarray:
    """d(T x)/d xi for points ``x`` [N, 3] -> [N, 3, dim]: ``[-s R [x]x, s R, s R x]``."""
    N = len(x)
    J = np.empty((N, 3, group_dim(group)))
    sR = s * R
    J[:, :, 0:3] = -sR @ skew_batch(x)
    J[:, :, 3:6] = sR
    if group == "sim3":
        J[:, :, 6] = x @ sR.T
    return J


def inverse_action_jacobian(z: np.ndarray, group: str) -> np.ndarray:
    """d(T^-1 y)/d xi at ``z = T^-1 y`` [N, 3] -> [N, 3, dim]: ``[[z]x, -I, -z]``."""
    N = len(z)
    J = np.empty((N, 3, group_dim(group)))
    J[:, :, 0:3] = skew_batch(z)
    J[:, :, 3:6] = -np.eye(3)
    if group == "sim3":
        J[:, :, 6] = -z
    return J


def so3_log(R: np.ndarray) -> np.ndarray:  # [3, 3] -> [3]
    return np.asarray(gtsam.Rot3.Logmap(gtsam.Rot3(R)))


def so3_right_jacobian_inv(w: np.ndarray) -> np.ndarray:  # [3] -> [3, 3]
    """Inverse right Jacobian of SO(3): d Log(R0 Exp(d)) / d d at ``w = Log(R0)``."""
    theta = float(np.linalg.norm(w))
    W = skew_batch(w[None])[0]
    if theta < 1e-6:
        return np.eye(3) + 0.5 * W + W @ W / 12.0
    c = 1.0 / theta**2 - (1.0 + np.cos(theta)) / (2.0 * theta * np.sin(theta))
    return np.eye(3) + 0.5 * W + c * W @ W


def check_finite(name: str, a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if not np.all(np.isfinite(a)):
        bad = int((~np.isfinite(a)).sum())
        raise FactorInputError(f"{name} holds {bad} NaN/inf entries; drop those measurements first")
    return a


def check_shape(name: str, a: np.ndarray, shape: tuple) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim != len(shape) or any(e is not None and e != n for e, n in zip(shape, a.shape)):
        want = "[" + ", ".join("N" if e is None else str(e) for e in shape) + "]"
        raise FactorInputError(f"{name} must be {want}, got {list(a.shape)}")
    return check_finite(name, a)


def check_count(name: str, n: int, minimum: int = 3) -> None:
    if n < minimum:
        raise FactorInputError(f"{name}: need at least {minimum} correspondences, got {n}")


def check_positive(name: str, v: float) -> float:
    v = float(v)
    if not (np.isfinite(v) and v > 0):
        raise FactorInputError(f"{name} must be a positive finite number, got {v}")
    return v


def pose_sigmas(rot_sigma: float, trans_sigma: float) -> np.ndarray:  # -> [6]: rotation first, GTSAM's order
    """The diagonal sigmas of a pose residual (rad x3, then translation x3), each checked positive."""
    rot, trans = check_positive("rot_sigma", rot_sigma), check_positive("trans_sigma", trans_sigma)
    return np.array([rot] * 3 + [trans] * 3)


def fill(H, i: int, J: np.ndarray) -> None:
    """Write Jacobian block ``J`` into CustomFactor's output list ``H`` (when requested)."""
    if H is not None:
        H[i] = J


def sim3_pair_factor(noise, key_a: int, key_b: int, residual) -> gtsam.CustomFactor:
    """A CustomFactor on two Similarity3 keys from ``residual(S_a, S_b, want_jacobians) -> (r, J_a, J_b)``."""

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        ka, kb = this.keys()
        S_a, S_b = read_transform(values, ka, "sim3"), read_transform(values, kb, "sim3")
        r, JA, JB = residual(S_a, S_b, H is not None)
        fill(H, 0, JA)
        fill(H, 1, JB)
        return r

    return gtsam.CustomFactor(noise, [key_a, key_b], error)
