"""Dense depth of a monocular window, once its local poses are known (step 5 of the mono encoder).

Every keyframe gets a depth per point-map pixel by two-ray triangulation of its flow to the keyframe
with the widest baseline (:func:`dense_depth`); its confidence grows with the parallax angle
(parallax / (4 ``encoder.min_parallax_deg``), clipped to [0, 1]: the shared depth's confidence read by
the next window, :mod:`gsslam.frontend.mono_link`). A keyframe whose triangulation gave (almost) nothing
gets frame 0's depth carried into it through its flow (:func:`fill_missing_depth`, confidence at most
:data:`PROPAGATED_CONFIDENCE`), or frame 0's median depth as a plane with confidence 0: any keyframe may
become the next window's shared frame, whose depth chains the scale.
"""

from __future__ import annotations

import numpy as np

from gsslam.config import EncoderConfig
from gsslam.frontend.flow import FlowEstimator, compose_flows, forward_backward_mask, textured_mask
from gsslam.frontend.two_view import triangulate_rays
from gsslam.geometry import depth_to_points, invert_T
from gsslam.types import CameraIntrinsics

FB_THRESHOLD_PX = 1.0  # forward-backward check of the flows (point-map pixels)
PROPAGATED_CONFIDENCE = 0.5  # depth carried from another frame (or the shared depth), not triangulated


def dense_depth(
    flow: FlowEstimator,  # for the flows between two keyframes other than frame 0
    imgs: list[np.ndarray],  # [h, w, 3] the keyframes at point-map resolution
    fw: list,  # [h, w, 2] chained flow 0 -> i (gsslam.frontend.flow.chained_flows)
    bw: list,  # [h, w, 2] chained flow i -> 0
    valid: list,  # [h, w] bool, forward-backward checked and textured 0 -> i
    T_local: np.ndarray,  # [n, 4, 4] T_local_cam of each keyframe
    intr: CameraIntrinsics,  # point-map intrinsics
    cfg: EncoderConfig,
) -> tuple[np.ndarray, np.ndarray]:  # [n, h, w, 3] points (NaN: none), [n, h, w] confidence
    """Per-frame depth from two-ray triangulation against the widest-baseline partner."""
    n, (h, w) = len(imgs), imgs[0].shape[:2]
    K = intr.K
    centers = T_local[:, :3, 3]
    uv = np.stack(np.meshgrid(np.arange(w), np.arange(h)), -1).reshape(-1, 2).astype(np.float64)
    points = np.full((n, h, w, 3), np.nan, np.float32)
    conf = np.zeros((n, h, w), np.float32)
    for i in range(n):
        j = int(np.argmax(np.linalg.norm(centers - centers[i], axis=1)))
        if i == 0:
            f_ij, ok = fw[j], valid[j]
        elif j == 0:
            f_ij = bw[i]
            ok = forward_backward_mask(
                np.nan_to_num(bw[i], nan=1e6),
                np.nan_to_num(fw[i], nan=1e6),
                FB_THRESHOLD_PX,
                relative=0.01,
            ) & textured_mask(imgs[i], cfg.min_texture_gradient)
        else:
            init = compose_flows(bw[i], fw[j])
            f_ij = flow(imgs[i], imgs[j], init=np.nan_to_num(init))
            f_ji = flow(imgs[j], imgs[i], init=np.nan_to_num(compose_flows(bw[j], fw[i])))
            ok = forward_backward_mask(f_ij, f_ji, FB_THRESHOLD_PX, relative=0.01) & textured_mask(
                imgs[i], cfg.min_texture_gradient
            )
        T_j_i = invert_T(T_local[j]) @ T_local[i]
        X, par, err = triangulate_rays(K, uv, uv + np.nan_to_num(f_ij.reshape(-1, 2)), T_j_i)
        good = (
            ok.reshape(-1)
            & np.isfinite(X).all(1)
            & (err < 2.0 * cfg.ransac_threshold_px)
            & (par > 0.5 * cfg.min_parallax_deg)
        )
        X[~good] = np.nan
        points[i] = X.reshape(h, w, 3)
        conf[i] = np.where(good, np.clip(par / (4.0 * cfg.min_parallax_deg), 0.0, 1.0), 0.0).reshape(h, w)
    return points, conf


def propagate(P0: np.ndarray, bw_i: np.ndarray, T_i_0: np.ndarray) -> np.ndarray:  # -> [h, w, 3]
    """Frame-0 points [h, w, 3] carried into frame i through its backward flow i -> 0 [h, w, 2] and
    ``T_i_0`` [4, 4] (NaN where the flow leaves the image or the point is behind the camera)."""
    h, w = P0.shape[:2]
    tgt = np.stack(np.meshgrid(np.arange(w), np.arange(h)), -1) + np.nan_to_num(bw_i, nan=-1e6)
    ti = np.round(tgt).astype(int)
    inside = (ti[..., 0] >= 0) & (ti[..., 0] < w) & (ti[..., 1] >= 0) & (ti[..., 1] < h)
    X0 = np.full((h, w, 3), np.nan)
    X0[inside] = P0[ti[inside][:, 1], ti[inside][:, 0]]
    Xi = X0.reshape(-1, 3) @ T_i_0[:3, :3].T + T_i_0[:3, 3]
    Xi[~(Xi[:, 2] > 0)] = np.nan
    return Xi.reshape(h, w, 3)


def fill_missing_depth(
    points: np.ndarray,  # [n, h, w, 3], filled in place
    conf: np.ndarray,  # [n, h, w], filled in place
    bw: list,  # [h, w, 2] chained flow i -> 0
    T_local: np.ndarray,  # [n, 4, 4]
    K: np.ndarray,  # [3, 3] point-map intrinsics
    min_inliers: int,  # fewer depth pixels than this is "nothing"
    meta: dict,  # gets "depth_propagated" (frames), "placeholder_depth"
) -> None:
    """A frame whose triangulation gave (almost) nothing gets frame 0's depth carried into it.

    Every keyframe of a submap may become the shared frame of the next one, whose scale is
    chained through this depth: a submap must never leave a frame without depth.
    """
    for i in range(1, len(points)):
        if np.isfinite(points[i, ..., 2]).sum() >= min_inliers:
            continue
        Xi = propagate(points[0], bw[i], invert_T(T_local[i]))
        points[i] = Xi
        conf[i] = np.where(np.isfinite(Xi[..., 2]), np.minimum(conf[0], PROPAGATED_CONFIDENCE), 0.0)
        meta.setdefault("depth_propagated", []).append(i)
        if np.isfinite(Xi[..., 2]).sum() < min_inliers:  # no flow either: frame 0 as a plane
            z0 = float(np.nanmedian(points[0, ..., 2])) if np.isfinite(points[0, ..., 2]).any() else 1.0
            points[i] = depth_to_points(K, np.full(points.shape[1:3], z0, np.float32))
            conf[i] = 0.0
            meta["placeholder_depth"] = True
