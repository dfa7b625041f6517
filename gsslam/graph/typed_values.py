"""Typed access to gtsam values: a value's gtsam type name, its tangent dimension, a factor's keys."""

from __future__ import annotations

import gtsam
import numpy as np


def value_at(values: gtsam.Values, key: int, type_name: str):
    """``values.at<type_name>(key)``, e.g. ``value_at(v, k, "Pose3")``."""
    return getattr(values, f"at{type_name}")(key)


def dim_at(values: gtsam.Values, key: int, type_name: str) -> int:
    return value_dim(value_at(values, key, type_name))


def value_dim(v) -> int:
    """Tangent dimension of a gtsam value (``ConstantBias`` has no ``dim()`` in the binding)."""
    if isinstance(v, (float, int, np.ndarray)):
        return int(np.size(v))
    if isinstance(v, gtsam.imuBias.ConstantBias):
        return 6
    return int(v.dim())


def factor_keys(factor) -> str:
    """A factor's keys as ``s0,s1`` (for messages)."""
    return ",".join(gtsam.DefaultKeyFormatter(k) for k in factor.keys())


def type_name(value) -> str:
    """The gtsam type name of a value, as in ``Values.at<type_name>``."""
    if isinstance(value, (float, int)):
        return "Double"
    if isinstance(value, np.ndarray):
        return "Vector"
    if isinstance(value, gtsam.imuBias.ConstantBias):
        return "ConstantBias"
    return type(value).__name__
