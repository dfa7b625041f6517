"""Cheap CPU appearance: a blurred, normalised tiny image per keyframe and ORB features.

The global descriptor is the keyframe downsampled to 16x12 after a Gaussian blur, made zero-mean
and unit-norm; the appearance overlap of two views is their normalised cross-correlation clipped
to [0, 1] (0 for unrelated views, 1 for the same view). It is a coarse place-recognition cue
(weight 0.3 in the candidate score); geometry decides (reprojection overlap, then RANSAC).
"""

from __future__ import annotations

import cv2
import numpy as np

from gsslam.loop.types import LoopError, ViewFeatures

TINY_SIZE = (16, 12)  # (w, h) of the tiny image
ORB_MIN_SIDE = 320  # small keyframes are upsampled to this width before ORB


def _as_uint8(gray: np.ndarray) -> np.ndarray:  # gray [h, w] float in [0, 1] or uint8
    if gray.ndim != 2:
        raise LoopError(f"keyframe images must be grayscale [h, w], got shape {gray.shape}")
    if gray.dtype == np.uint8:
        return gray
    return (np.clip(np.nan_to_num(gray), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def global_descriptor(gray: np.ndarray) -> np.ndarray:  # gray [h, w] -> [192] float32, unit norm
    img = _as_uint8(gray).astype(np.float32)
    sigma = 0.5 * img.shape[1] / TINY_SIZE[0]
    img = cv2.GaussianBlur(img, (0, 0), sigmaX=max(sigma, 0.5))
    tiny = cv2.resize(img, TINY_SIZE, interpolation=cv2.INTER_AREA).reshape(-1)
    tiny = tiny - tiny.mean()
    n = float(np.linalg.norm(tiny))
    return (tiny / n if n > 1e-6 else np.zeros_like(tiny)).astype(np.float32)


def appearance_overlap(desc_a: np.ndarray, desc_b: np.ndarray) -> np.ndarray:
    """NCC of every view pair clipped to [0, 1]: ``desc_a`` [A, D], ``desc_b`` [B, D] -> [A, B]."""
    return np.clip(desc_a @ desc_b.T, 0.0, 1.0)


def orb_features(
    gray: np.ndarray, points_cam: np.ndarray, T_local_cam: np.ndarray, n_features: int
) -> ViewFeatures:
    """ORB keypoints of one keyframe lifted to submap-local 3D by its point map.

    ``gray``: [H, W] image (any resolution with the point map's aspect ratio); ``points_cam``:
    [h, w, 3] the view's point map (NaN unknown); ``T_local_cam``: [4, 4]. Keypoints without a
    3D point are dropped; coordinates are returned at point-map resolution.
    """
    img = _as_uint8(gray)
    h, w = points_cam.shape[:2]
    up = max(1.0, ORB_MIN_SIDE / img.shape[1])
    if up > 1.0:
        img = cv2.resize(img, None, fx=up, fy=up, interpolation=cv2.INTER_LINEAR)
    orb = cv2.ORB_create(
        nfeatures=n_features, scaleFactor=1.2, nlevels=4, edgeThreshold=15, patchSize=15, fastThreshold=10
    )
    kps, desc = orb.detectAndCompute(img, None)
    if desc is None or len(kps) == 0:
        return ViewFeatures(np.zeros((0, 2)), np.zeros((0, 32), np.uint8), np.zeros((0, 3)))
    uv = np.array([k.pt for k in kps], dtype=np.float64)  # [F, 2] in the (upsampled) image
    uv_pm = (uv + 0.5) * np.array([w / img.shape[1], h / img.shape[0]]) - 0.5
    ui = np.clip(np.round(uv_pm[:, 0]).astype(int), 0, w - 1)
    vi = np.clip(np.round(uv_pm[:, 1]).astype(int), 0, h - 1)
    X = points_cam[vi, ui].astype(np.float64)  # [F, 3]
    ok = np.isfinite(X).all(axis=1) & (X[:, 2] > 0)
    X_local = X[ok] @ T_local_cam[:3, :3].T + T_local_cam[:3, 3]
    return ViewFeatures(uv_pm[ok], desc[ok], X_local)
