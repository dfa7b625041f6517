"""Factor specs: a factor as plain data (maker name + numpy/scalar arguments), rebuilt on demand.

GTSAM's ``CustomFactor`` holds a Python callback and cannot be serialized. The SLAM graph therefore
builds every factor from a *spec* ``(kind, args, kwargs)`` whose arguments are ints, floats, strings
and numpy arrays, and hands the spec to :class:`gsslam.graph.backend.Backend` with the factor. A
checkpoint stores the specs; :func:`build_factor` turns one back into the identical factor, and the
backend replays its updates (:meth:`~gsslam.graph.backend.Backend.replay`). Only the makers listed in
:data:`MAKERS` can be named: a spec never calls anything else.
"""

from __future__ import annotations

from typing import Any

import gtsam
import numpy as np

from gsslam.errors import GsslamError
from gsslam.factors import (
    make_depth_prior_factor,
    make_flow_factor,
    make_keyframe_pose_factor,
    make_point_factor,
    make_ray_point_factor,
    make_registration_factor,
    make_relative_point_factor,
    make_relative_pose_factor,
    make_relative_registration_factor,
    make_scale_factor,
    make_scale_prior_factor,
    make_submap_alignment_factor,
)
from gsslam.factors.stretch import (
    make_stretch_prior_factor,
    make_stretched_alignment_factor,
    make_stretched_flow_factor,
    make_stretched_point_factor,
    make_stretched_ray_point_factor,
)

FactorSpec = tuple[str, tuple, dict]  # (kind, positional args, keyword args), plain data only


class FactorSpecError(GsslamError):
    """A spec names a maker that is not in :data:`MAKERS` (or its arguments do not fit it)."""


def make_sim3_prior_factor(key: int, sigmas: np.ndarray) -> gtsam.NonlinearFactor:
    """Prior on a Sim(3) variable at the identity; ``sigmas`` [7] in the chart order (rot, trans, scale)."""
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, dtype=np.float64))
    return gtsam.PriorFactorSimilarity3(int(key), gtsam.Similarity3(), noise)


MAKERS = {
    "sim3_prior": make_sim3_prior_factor,
    "submap_alignment": make_submap_alignment_factor,
    "scale": make_scale_factor,
    "scale_prior": make_scale_prior_factor,
    "point": make_point_factor,
    "relative_point": make_relative_point_factor,
    "ray_point": make_ray_point_factor,
    "relative_pose": make_relative_pose_factor,
    "flow": make_flow_factor,
    "registration": make_registration_factor,
    "relative_registration": make_relative_registration_factor,
    "depth_prior": make_depth_prior_factor,
    "keyframe_pose": make_keyframe_pose_factor,
    "stretch_prior": make_stretch_prior_factor,
    "stretched_alignment": make_stretched_alignment_factor,
    "stretched_point": make_stretched_point_factor,
    "stretched_flow": make_stretched_flow_factor,
    "stretched_ray_point": make_stretched_ray_point_factor,
}


def spec(kind: str, *args: Any, **kwargs: Any) -> FactorSpec:
    if kind not in MAKERS:
        raise FactorSpecError(f"unknown factor kind {kind!r}; known: {', '.join(MAKERS)}")
    return kind, tuple(args), dict(kwargs)


def build_factor(s: FactorSpec) -> gtsam.NonlinearFactor:
    """The factor a spec describes (the same maker, the same arguments)."""
    kind, args, kwargs = s
    if kind not in MAKERS:
        raise FactorSpecError(f"unknown factor kind {kind!r} in a factor spec")
    try:
        return MAKERS[kind](*args, **kwargs)
    except (TypeError, ValueError) as e:
        raise FactorSpecError(f"factor spec {kind!r}: {e}") from e
