"""The inlier test of mono loop verification: a noise model shaped like a mono point map's error.

A monocular point map is accurate across the viewing ray (the keypoint's pixel, about a pixel) and
poor along it (triangulated depth: 5-10 % of the depth on hand-held footage, more at low parallax).
An isotropic 3D gate (``|T X_m - X_i| < 2 % of the median depth``) therefore rejects most right
matches of a noisy submap, while a looser isotropic gate would let wrong matches in across the ray.

The ray gate measures the residual of a match in the camera of submap i that saw ``X_i`` (view a):
``x = T_a_local X_i`` and ``y = T_a_local T_i_m X_m``; the pair is an inlier when the angle between
the two rays is below ``ray_threshold_deg`` (the pixel error, scale-free) and their ranges agree
within ``ray_depth_rel`` (``| |y| - |x| | <= ray_depth_rel |x|``, the point map's depth noise).
Both bounds are relative, so the test is the same at any submap scale.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from gsslam.geometry import invert_T, transform_points


def ray_residuals(
    X_i: np.ndarray,  # [N, 3] submap-i local
    Y: np.ndarray,  # [N, 3] T_i_m X_m, submap-i local
    T_cam_local: np.ndarray,  # [N, 4, 4] per match: submap-i local -> camera of the view that saw X_i
) -> tuple[np.ndarray, np.ndarray]:  # angle [N] radians, range error [N] relative to |x|
    R, t = T_cam_local[:, :3, :3], T_cam_local[:, :3, 3]
    x = np.einsum("nij,nj->ni", R, X_i) + t
    y = np.einsum("nij,nj->ni", R, Y) + t
    nx, ny = np.linalg.norm(x, axis=1), np.linalg.norm(y, axis=1)
    angle = np.arctan2(np.linalg.norm(np.cross(x, y), axis=1), np.einsum("ni,ni->n", x, y))
    return angle, np.abs(ny - nx) / np.maximum(nx, 1e-12)


def ray_inlier_test(
    X_i: np.ndarray,  # [N, 3]
    X_m: np.ndarray,  # [N, 3]
    view_i: np.ndarray,  # [N] view of submap i each X_i was seen in
    T_local_cam: np.ndarray,  # [V, 4, 4] submap i's keyframe poses (rigid, local units)
    max_angle_deg: float,
    max_depth_rel: float,
) -> Callable[[np.ndarray], np.ndarray]:
    """``T_i_m`` -> [N] bool: which pairs pass the ray gate under that transform."""
    T_cam_local = invert_T(T_local_cam)[view_i]  # [N, 4, 4]
    max_angle = np.radians(max_angle_deg)

    def test(T_i_m: np.ndarray) -> np.ndarray:
        angle, depth_rel = ray_residuals(X_i, transform_points(T_i_m, X_m), T_cam_local)
        return (angle < max_angle) & (depth_rel < max_depth_rel)

    return test


def range_inlier_test(
    X_i: np.ndarray,  # [N, 3]
    X_m: np.ndarray,  # [N, 3]
    view_i: np.ndarray,  # [N]
    T_local_cam: np.ndarray,  # [V, 4, 4]
    max_rel: float,
) -> Callable[[np.ndarray], np.ndarray]:
    """``T_i_m`` -> [N] bool: ``|T X_m - X_i| < max_rel x`` the range of ``X_i`` in the view that saw it
    (an isotropic gate that grows with each point's own depth, like the point map's noise)."""
    T_cam_local = invert_T(T_local_cam)[view_i]  # [N, 4, 4]
    rng_i = np.linalg.norm(
        np.einsum("nij,nj->ni", T_cam_local[:, :3, :3], X_i) + T_cam_local[:, :3, 3], axis=1
    )

    def test(T_i_m: np.ndarray) -> np.ndarray:
        return np.linalg.norm(transform_points(T_i_m, X_m) - X_i, axis=1) < max_rel * rng_i

    return test
