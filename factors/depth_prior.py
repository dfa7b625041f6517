"""Depth prior from the Gaussian map (mapper feedback) on a Similarity3 submap variable.

The mapper renders refined depths ``z_r`` (world units) at N pixels of a keyframe. The graph knows
the keyframe's local points there (depth ``z_l`` in the submap's units, camera frame). With the
submap variable ``S = (R, t, s)`` the keyframe's world-scaled depth is ``s z_l`` (a rigid change of
the camera pose does not change a depth measured along the camera's own ray), so::

    r_k = (log(s z_l[k]) - log z_r[k]) / sigma          k = 1..N, dimension N

``sigma`` is relative (log-depth) noise. Jacobian: ``dr_k / dlambda = 1 / sigma``, zero for rotation
and translation. It constrains the submap's scale; the pose enters through the other factors.
"""

from __future__ import annotations

import gtsam
import numpy as np

from ._lie import check_count, check_positive, check_shape, fill
from .errors import FactorInputError


def make_depth_prior_factor(
    key: int,
    depth_local: np.ndarray,  # [N] z of the keyframe's local points (submap units)
    depth_rendered: np.ndarray,  # [N] rendered depth (world units)
    sigma: float,
) -> gtsam.CustomFactor:
    """Batched log-depth prior on the scale of one Similarity3 variable, residual dimension N."""
    zl = check_shape("depth_local", depth_local, (None,))
    zr = check_shape("depth_rendered", depth_rendered, (len(zl),))
    check_count("depth prior", len(zl))
    if np.any(zl <= 0) or np.any(zr <= 0):
        raise FactorInputError("depth_local and depth_rendered must be positive")
    w = 1.0 / check_positive("sigma", sigma)
    offset = np.log(zl) - np.log(zr)
    J = np.zeros((len(zl), 7))
    J[:, 6] = w

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        fill(H, 0, J)
        return (np.log(values.atSimilarity3(this.keys()[0]).scale()) + offset) * w

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(len(zl)), [key], error)
