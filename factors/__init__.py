"""Custom GTSAM factors of gsslam: residuals with analytic Jacobians. Depends on gtsam and numpy only.

Every ``make_*_factor`` returns a ``gtsam.CustomFactor`` whose Jacobians are in GTSAM's
right-perturbation chart (see :mod:`factors._lie`); batched factors carry all points of one pair.
See docs/factors.md for residuals, dimensions, frames and units.
"""

from ._lie import to_gtsam, to_matrix
from .depth_prior import make_depth_prior_factor
from .errors import FactorInputError
from .flow import make_flow_factor, mixture_weights
from .keyframe_pose import make_keyframe_pose_factor
from .keyframe_tie import make_keyframe_tie_factor
from .loop_points import make_relative_point_factor
from .loop_rays import make_ray_point_factor
from .points import make_point_factor
from .registration import make_registration_factor
from .relative_pose import make_relative_pose_factor
from .relative_registration import make_relative_registration_factor
from .scale import make_scale_factor, make_scale_prior_factor, median_depth_ratio
from .submap_alignment import make_submap_alignment_factor

__all__ = [
    "FactorInputError",
    "make_depth_prior_factor",
    "make_flow_factor",
    "make_keyframe_pose_factor",
    "make_keyframe_tie_factor",
    "make_point_factor",
    "make_registration_factor",
    "make_ray_point_factor",
    "make_relative_point_factor",
    "make_relative_registration_factor",
    "make_relative_pose_factor",
    "make_scale_factor",
    "make_scale_prior_factor",
    "make_submap_alignment_factor",
    "median_depth_ratio",
    "mixture_weights",
    "to_gtsam",
    "to_matrix",
]
