"""Depth seen from the colour camera: the re-projection that registers an unregistered depth image.

:func:`reproject_depth` moves each depth pixel into the colour camera (back-project with the depth
camera's intrinsics, turn by ``R_colour_depth`` when the depth camera is turned against the colour camera,
shift by the baseline along x, project with the colour intrinsics; the nearest surface wins) and optionally
reads the depth image at each colour pixel's exact depth pixel. :mod:`gsslam.frontend.depth_registration`
estimates the registration and applies it with this (moved here from there in session 16). A full rigid
transform (``t_colour_depth``, a 3-vector, with ``R_colour_depth``) moves the depth of a frame whose depth
image was taken at another time than its colour image (:mod:`gsslam.frontend.depth_retiming`, session 17).
"""

from __future__ import annotations

import numpy as np

from gsslam.types import CameraIntrinsics


def reproject_depth(
    depth: np.ndarray,  # [H, W] metres in the depth camera's grid, NaN invalid
    depth_intr: CameraIntrinsics,
    colour_intr: CameraIntrinsics,
    baseline_m: float,  # the depth camera's centre in the colour camera frame, along x
    mean_tol: float = 0.0,  # > 0: the mean of the samples within this relative depth of the nearest
    interp_tol: float = 0.0,  # > 0: then read the depth image at the exact pixel where its 4 neighbours agree
    R_colour_depth: np.ndarray | None = None,  # [3, 3] the depth camera's turn (None: none; session 16)
    t_colour_depth: np.ndarray | None = None,  # [3] its centre in the colour frame (None: (baseline_m, 0, 0))
) -> np.ndarray:  # [H, W] float32 metres at the colour pixels, NaN where nothing lands
    """Depth seen from the colour camera: back-project, shift by the baseline, project, nearest wins.

    A magnifying projection (colour focal longer than depth's) fills the up-to-4 pixels around each
    projection so that no cracks open; otherwise each point lands on its nearest pixel. Where several
    noisy samples of one surface land on a pixel (a Kinect v1's depth camera samples 1.114x finer than
    its colour camera) the nearest is the noise's minimum, biased towards the camera; ``mean_tol`` > 0
    averages the samples within ``mean_tol * z`` of the nearest instead (the nearest surface still wins).
    Each sample lands on the nearest pixel, up to half a pixel from where it projects; ``interp_tol`` > 0
    then reads the depth image bilinearly at the exact depth pixel of each colour pixel (its ray shifted by
    the baseline at the z-buffer's depth), where the 4 depth pixels lie within ``interp_tol * z`` of it.
    ``t_colour_depth`` given, the depth camera's centre is that 3-vector instead of ``(baseline_m, 0, 0)``:
    with ``R_colour_depth``, ``X_colour = R X_depth + t``, any rigid transform.
    """
    h, w = depth.shape
    rigid = _rigid(R_colour_depth, t_colour_depth, baseline_m)
    vs, us = np.nonzero(np.isfinite(depth) & (depth > 0))
    z = depth[vs, us].astype(np.float64)
    x = (us - depth_intr.cx) / depth_intr.fx * z + baseline_m
    y = (vs - depth_intr.cy) / depth_intr.fy * z
    if rigid is not None:  # X_colour = R (X_depth) + t: the cloud stays rigid
        R, t = rigid
        Xc = np.stack([x - baseline_m, y, z], 1) @ R.T
        x, y, z = Xc[:, 0] + t[0], Xc[:, 1] + t[1], Xc[:, 2] + t[2]
    u = colour_intr.cx + colour_intr.fx * x / z
    v = colour_intr.cy + colour_intr.fy * y / z
    if colour_intr.fx > depth_intr.fx * 1.0001:
        cands = [
            (np.floor(u), np.floor(v)),
            (np.floor(u), np.ceil(v)),
            (np.ceil(u), np.floor(v)),
            (np.ceil(u), np.ceil(v)),
        ]
    else:
        cands = [(np.rint(u), np.rint(v))]
    out = np.full(h * w, np.inf)
    hits = []
    for uu, vv in cands:
        ok = (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h)
        hits.append(((vv[ok] * w + uu[ok]).astype(np.int64), z[ok]))
        np.minimum.at(out, *hits[-1])
    if mean_tol > 0:
        idx = np.concatenate([i for i, _ in hits])
        zz = np.concatenate([q for _, q in hits])
        near = zz <= out[idx] * (1.0 + mean_tol)  # the nearest surface's samples
        tot = np.bincount(idx[near], zz[near], h * w)
        cnt = np.bincount(idx[near], None, h * w)
        out = np.where(cnt > 0, tot / np.maximum(cnt, 1), out)
    out[~np.isfinite(out)] = np.nan
    out = out.reshape(h, w)
    if interp_tol > 0:
        out = _interpolate_at_colour_pixels(
            out, depth, depth_intr, colour_intr, baseline_m, interp_tol, rigid
        )
    return out.astype(np.float32)


def _rigid(R: np.ndarray | None, t: np.ndarray | None, baseline_m: float):  # -> (R [3, 3], t [3]) | None
    """The depth camera's pose in the colour frame when it is more than a baseline along x (None: not)."""
    if R is None and t is None:
        return None
    R = np.eye(3) if R is None else np.asarray(R, dtype=np.float64)
    t = np.array([baseline_m, 0.0, 0.0]) if t is None else np.asarray(t, dtype=np.float64).reshape(3)
    return R, t


def _interpolate_at_colour_pixels(
    z_col: np.ndarray,  # [H, W] the z-buffer's depth at the colour pixels, NaN none
    depth: np.ndarray,  # [H, W] the depth image (depth camera grid)
    depth_intr: CameraIntrinsics,
    colour_intr: CameraIntrinsics,
    baseline_m: float,
    tol: float,
    rigid: tuple[np.ndarray, np.ndarray] | None = None,  # (R_colour_depth [3, 3], t_colour_depth [3])
) -> np.ndarray:  # [H, W] float64
    h, w = z_col.shape
    vs, us = np.nonzero(np.isfinite(z_col))
    z = z_col[vs, us]
    scale = None  # a turned (or moved) depth camera: its z along the colour ray is z * scale
    if rigid is None:
        ud = depth_intr.cx + depth_intr.fx * ((us - colour_intr.cx) / colour_intr.fx - baseline_m / z)
        vd = depth_intr.cy + depth_intr.fy * (vs - colour_intr.cy) / colour_intr.fy
    else:
        ray = np.stack([(us - colour_intr.cx) / colour_intr.fx, (vs - colour_intr.cy) / colour_intr.fy,
                        np.ones(len(us))], 1)  # fmt: skip
        Xd = (ray * z[:, None] - rigid[1]) @ rigid[0]  # R^T (X - t)
        ud = depth_intr.cx + depth_intr.fx * Xd[:, 0] / Xd[:, 2]
        vd = depth_intr.cy + depth_intr.fy * Xd[:, 1] / Xd[:, 2]
        scale, z = Xd[:, 2] / z, Xd[:, 2]  # compare and interpolate in the depth camera's z
    u0, v0 = np.floor(ud).astype(np.int64), np.floor(vd).astype(np.int64)
    inside = (u0 >= 0) & (u0 + 1 < w) & (v0 >= 0) & (v0 + 1 < h)
    vs, us, z, ud, vd, u0, v0 = (a[inside] for a in (vs, us, z, ud, vd, u0, v0))
    scale = None if scale is None else scale[inside]
    fu, fv = ud - u0, vd - v0
    d = np.nan_to_num(np.asarray(depth, np.float64), nan=-1.0)
    q = [d[v0, u0], d[v0, u0 + 1], d[v0 + 1, u0], d[v0 + 1, u0 + 1]]
    wts = [(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv]
    agree = np.all([np.abs(x - z) <= tol * z for x in q], axis=0)
    val = sum(wt * x for wt, x in zip(wts, q))
    if scale is not None:
        val = val / scale  # back to the colour camera's z (to first order in the baseline)
    out = z_col.copy()
    out[vs[agree], us[agree]] = val[agree]
    return out
