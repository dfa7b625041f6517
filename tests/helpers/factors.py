"""Shared helpers of the factor tests: random values away from identity, numeric vs analytic Jacobians."""

from __future__ import annotations

import gtsam
import numpy as np
from gtsam.utils.numerical_derivative import numericalDerivative11


def random_value(rng: np.random.Generator, group: str):
    """A random Pose3 / Similarity3 well away from identity."""
    R = gtsam.Rot3.Expmap(rng.uniform(-1.0, 1.0, 3))
    t = rng.uniform(-2.0, 2.0, 3)
    if group == "sim3":
        return gtsam.Similarity3(R, t, float(np.exp(rng.uniform(-0.5, 0.5))))
    return gtsam.Pose3(R, t)


def analytic_jacobians(factor, values: gtsam.Values) -> list[np.ndarray]:
    """Whitened Jacobian blocks of ``factor`` at ``values`` (what iSAM2 sees)."""
    lin = factor.linearize(values)
    return [np.asarray(lin.jacobian()[0][:, _cols(factor, values, i)]) for i in range(len(factor.keys()))]


def _cols(factor, values, i):
    dims = [values.atSimilarity3(k).dim() if _is_sim3(values, k) else 6 for k in factor.keys()]
    start = sum(dims[:i])
    return slice(start, start + dims[i])


def _is_sim3(values, key) -> bool:
    try:
        values.atSimilarity3(key)
        return True
    except RuntimeError:
        return False


def numeric_jacobians(factor, values: gtsam.Values, delta: float = 1e-6) -> list[np.ndarray]:
    """Central differences of the whitened error through each variable's ``retract`` (GTSAM's chart)."""
    out = []
    for key in factor.keys():
        base = values.atSimilarity3(key) if _is_sim3(values, key) else values.atPose3(key)

        def h(x, key=key):
            v = gtsam.Values(values)
            v.update(key, x)
            return factor.whitenedError(v)

        out.append(numericalDerivative11(h, base, delta))
    return out


def random_rigid_batch(rng: np.random.Generator, n: int) -> np.ndarray:  # [n, 4, 4] rigid poses
    poses = [gtsam.Pose3(gtsam.Rot3.Expmap(rng.uniform(-1, 1, 3)), rng.uniform(-1, 1, 3)) for _ in range(n)]
    return np.stack([p.matrix() for p in poses])


def random_information(rng: np.random.Generator, n: int) -> np.ndarray:  # [n, 6, 6] positive definite
    A = rng.normal(size=(n, 6, 6))
    return np.einsum("nij,nkj->nik", A, A) + 0.5 * np.eye(6)
