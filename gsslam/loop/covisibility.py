"""Covisibility: does an earlier submap's geometry reproject into the current submap's views?

Under the current world estimates ``T_world_local`` (Sim(3)), the subsampled points of submap m
are mapped into every view of submap i and projected. A point *overlaps* when it lands inside
the image in front of the camera and its depth agrees with the depth view i measured there
(within ``depth_tolerance_rel``): occluded points and points floating in free space do not count.
The overlap ratio is computed both ways (m into i, i into m) and the larger is kept, so a
submap seeing only part of the other still qualifies. A bounding-sphere test rejects far
submaps before any projection, vectorised over the whole map.
"""

from __future__ import annotations

import cv2
import numpy as np

from gsslam.geometry import invert_T, sim3_scale
from gsslam.loop.appearance import global_descriptor, orb_features
from gsslam.loop.types import LoopError, SubmapRecord
from gsslam.types import SubmapEncoding

DEPTH_SMALL_MAX_SIDE = 48  # visibility tests run on depth maps downscaled to this


def make_record(
    submap_id: int,
    enc: SubmapEncoding,
    images: np.ndarray,  # [V, H, W] grayscale keyframes (same order as enc.frame_indices)
    n_points: int,
    n_features: int,
    rng: np.random.Generator,
) -> SubmapRecord:
    """Compress one submap to what detection and verification need (bounded size)."""
    V, h, w = enc.points_cam.shape[:3]
    if len(images) != V:
        raise LoopError(
            f"submap {submap_id}: {len(images)} keyframe images for {V} point maps; give one per keyframe"
        )
    scale = min(1.0, DEPTH_SMALL_MAX_SIDE / max(h, w))
    intr = enc.intrinsics.scaled(scale) if scale < 1.0 else enc.intrinsics
    depth_small = np.stack(
        [
            cv2.resize(
                enc.points_cam[v, ..., 2].astype(np.float32),
                (intr.width, intr.height),
                interpolation=cv2.INTER_NEAREST,
            )
            for v in range(V)
        ]
    )
    valid = np.isfinite(enc.points_cam).all(axis=-1) & (enc.points_cam[..., 2] > 0)  # [V, h, w]
    vv, yy, xx = np.nonzero(valid)
    if len(vv) < 3:
        raise LoopError(f"submap {submap_id} has fewer than 3 valid points; cannot be used for loop closure")
    pick = rng.choice(len(vv), size=min(n_points, len(vv)), replace=False)
    vv, yy, xx = vv[pick], yy[pick], xx[pick]
    Xc = enc.points_cam[vv, yy, xx].astype(np.float64)  # [N, 3]
    R, t = enc.T_local_cam[vv, :3, :3], enc.T_local_cam[vv, :3, 3]
    X = np.einsum("nij,nj->ni", R, Xc) + t
    center = X.mean(axis=0)
    cams = enc.T_local_cam[:, :3, 3]
    radius = float(max(np.linalg.norm(X - center, axis=1).max(), np.linalg.norm(cams - center, axis=1).max()))
    feats = tuple(
        orb_features(images[v], enc.points_cam[v], enc.T_local_cam[v], n_features) for v in range(V)
    )
    return SubmapRecord(
        submap_id=submap_id,
        frame_indices=tuple(int(f) for f in enc.frame_indices),
        K=intr.K,
        T_local_cam=enc.T_local_cam.astype(np.float64),
        depth_small=depth_small,
        points_local=X,
        point_view=vv.astype(np.int32),
        center_local=center,
        radius=radius,
        appearance=np.stack([global_descriptor(images[v]) for v in range(V)]),
        features=feats,
        median_depth=float(np.median(Xc[:, 2])),
    )


def spheres_intersect(
    center_i: np.ndarray,  # [3] world
    radius_i: float,
    centers: np.ndarray,  # [M, 3] world
    radii: np.ndarray,  # [M]
) -> np.ndarray:  # [M] bool
    return np.linalg.norm(centers - center_i, axis=1) <= radius_i + radii


def _covisible(
    src: SubmapRecord,
    T_world_src: np.ndarray,
    dst: SubmapRecord,
    T_world_dst: np.ndarray,
    tol: float,
    max_angle_deg: float = 180.0,
) -> np.ndarray:  # [V_dst, N_src] bool: src point n agrees with dst view a
    T_dst_src = invert_T(T_world_dst) @ T_world_src  # src local -> dst local (dst units)
    X = src.points_local @ T_dst_src[:3, :3].T + T_dst_src[:3, 3]  # [N, 3]
    T_cam_local = invert_T(dst.T_local_cam)  # [V, 4, 4]
    similar = np.ones((len(dst.T_local_cam), len(X)), dtype=bool)
    if max_angle_deg < 180.0:  # the two views see the point from directions that far apart at most
        c_src = src.T_local_cam[src.point_view, :3, 3] @ T_dst_src[:3, :3].T + T_dst_src[:3, 3]  # [N, 3]
        r_src = X - c_src
        r_dst = X[None] - dst.T_local_cam[:, None, :3, 3]  # [V, N, 3]
        cos = np.einsum("vni,ni->vn", r_dst, r_src) / np.maximum(
            np.linalg.norm(r_dst, axis=2) * np.linalg.norm(r_src, axis=1), 1e-12
        )
        similar = cos >= np.cos(np.radians(max_angle_deg))
    Xc = np.einsum("vij,nj->vni", T_cam_local[:, :3, :3], X) + T_cam_local[:, None, :3, 3]  # [V, N, 3]
    z = Xc[..., 2]
    zs = np.where(z > 1e-9, z, 1.0)
    K = dst.K
    u = np.round(K[0, 0] * Xc[..., 0] / zs + K[0, 2]).astype(np.int64)
    v = np.round(K[1, 1] * Xc[..., 1] / zs + K[1, 2]).astype(np.int64)
    Vn, hs, ws = dst.depth_small.shape
    inside = (z > 1e-9) & (u >= 0) & (u < ws) & (v >= 0) & (v < hs)
    views = np.broadcast_to(np.arange(Vn)[:, None], z.shape)
    d = np.full(z.shape, np.nan)
    d[inside] = dst.depth_small[views[inside], v[inside], u[inside]]
    with np.errstate(invalid="ignore"):
        return inside & similar & np.isfinite(d) & (np.abs(z - d) <= tol * d)


def reprojection_overlap(
    rec_i: SubmapRecord,
    T_world_i: np.ndarray,  # [4, 4] Sim(3)
    rec_m: SubmapRecord,
    T_world_m: np.ndarray,  # [4, 4] Sim(3)
    depth_tolerance_rel: float,
    max_view_angle_deg: float = 180.0,
) -> tuple[float, np.ndarray]:
    """Overlap ratio in [0, 1] and the co-visibility counts [V_i, V_m] of the views of i and m.

    ``max_view_angle_deg``: a point counts for a view pair only when the two views' rays to it are
    at most this far apart (features do not match across wider viewpoint changes; 180: any).
    """
    a = max_view_angle_deg
    m_in_i = _covisible(rec_m, T_world_m, rec_i, T_world_i, depth_tolerance_rel, a)  # [V_i, N_m]
    i_in_m = _covisible(rec_i, T_world_i, rec_m, T_world_m, depth_tolerance_rel, a)  # [V_m, N_i]
    ratio = max(float(m_in_i.any(axis=0).mean()), float(i_in_m.any(axis=0).mean()))
    V_i, V_m = len(rec_i.T_local_cam), len(rec_m.T_local_cam)
    counts = np.zeros((V_i, V_m))
    for b in range(V_m):  # m's points from view b seen by view a of i
        counts[:, b] += m_in_i[:, rec_m.point_view == b].sum(axis=1)
    for a in range(V_i):
        counts[a, :] += i_in_m[:, rec_i.point_view == a].sum(axis=1)
    return ratio, counts


def world_sphere(rec: SubmapRecord, T_world_local: np.ndarray) -> tuple[np.ndarray, float]:
    c = T_world_local[:3, :3] @ rec.center_local + T_world_local[:3, 3]
    return c, rec.radius * sim3_scale(T_world_local)
