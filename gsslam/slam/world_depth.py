"""Mono: the depth of a keyframe rendered from the chain's earlier keyframe depths.

In a low-parallax turn the mono encoder carries the shared frame's depth from window to window
through the flow; the turn moves the view off it, and once too little is left the encoder hands on a
placeholder plane at its median depth: a guess of the scale after the turn (docs/results.md, "Mono
across turns, session 13"). But the view after a turn in a room looks at surfaces the walk saw
before, whose depth the chain measured in its own units. :func:`rendered_depth` projects the measured
depths (confidence > 0: triangulated or carried, not placeholder planes) of the chain's earlier
keyframes into the shared frame at its current pose, nearest surface per cell, in the units of the
submap that owns the frame. The pipeline hands that on instead of the exhausted carried depth
(``encoder.mono_world_depth``), so the next window's scale is measured against the earlier geometry.
"""

from __future__ import annotations

import logging

import numpy as np

from gsslam.frontend.mono_depth import PROPAGATED_CONFIDENCE
from gsslam.frontend.mono_encoder import unmeasured
from gsslam.geometry import backproject, sim3_scale
from gsslam.slam.chains import Chain, ChainKeyframe, keyframe_confidence

log = logging.getLogger(__name__)

CELL_PX = 2  # z-buffer cell (point-map pixels): sparse sources leave no see-through holes
STRIDE_PX = 2  # source pixels sampled per keyframe
OCCLUSION_REL = 0.1  # a cell keeps the points within this of its nearest one


def rendered_depth(
    chain: Chain,
    chains: list[Chain],
    keyframes: dict[int, ChainKeyframe],
    index: int,  # the keyframe to render (owned by ``chain``'s graph)
    K: np.ndarray,  # [3, 3] point-map intrinsics (every keyframe depth of the chain is at this size)
    shape: tuple[int, int],  # (h, w) of the point maps
    min_confidence: float = 1e-6,
) -> tuple[np.ndarray, int]:  # [h, w] depth in the owner submap's units (NaN: none), source keyframes
    """Earlier measured keyframe depths of ``chain`` seen from keyframe ``index`` (module docstring)."""
    h, w = shape
    graph = chain.graph
    sid_t, _ = graph.owner(index)
    T_t = graph.keyframe_pose(index)  # rigid, chain units
    s_t = sim3_scale(graph.submap_pose(sid_t))
    R_t, t_t = T_t[:3, :3], T_t[:3, 3]
    vs, us = np.mgrid[0:h:STRIDE_PX, 0:w:STRIDE_PX]
    uv = np.stack([us.ravel(), vs.ravel()], 1).astype(np.float64)
    pts, used = [], 0
    cid = chains.index(chain)
    for idx, kf in keyframes.items():
        if idx == index or kf.chain != cid or kf.depth.shape != (h, w):
            continue
        conf = keyframe_confidence(chains, kf)
        if conf is None:
            continue
        z = kf.depth[vs, us].ravel().astype(np.float64)
        c = conf[vs, us].ravel()
        ok = np.isfinite(z) & (z > 0) & (c >= min_confidence)
        if not ok.any():
            continue
        T_j = graph.keyframe_pose(idx)
        s_j = sim3_scale(graph.submap_pose(kf.submap))
        X = s_j * backproject(K, uv[ok], z[ok])  # chain units, camera j
        X = X @ T_j[:3, :3].T + T_j[:3, 3]
        pts.append(((X - t_t) @ R_t) / s_t)  # camera t, its submap's units
        used += 1
    out = np.full((h, w), np.nan, np.float32)
    if not pts:
        return out, 0
    X = np.concatenate(pts)
    X = X[X[:, 2] > 1e-6]
    u = K[0, 0] * X[:, 0] / X[:, 2] + K[0, 2]
    v = K[1, 1] * X[:, 1] / X[:, 2] + K[1, 2]
    inb = (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    if not inb.any():
        return out, used
    cu = (np.round(u[inb]).astype(int)) // CELL_PX
    cv = (np.round(v[inb]).astype(int)) // CELL_PX
    z = X[inb, 2]
    gw, gh = (w + CELL_PX - 1) // CELL_PX, (h + CELL_PX - 1) // CELL_PX
    cell = cv * gw + cu
    near = np.full(gw * gh, np.inf)
    np.minimum.at(near, cell, z)
    keep = z <= near[cell] * (1.0 + OCCLUSION_REL)  # the nearest surface of each cell
    total = np.zeros(gw * gh)
    count = np.zeros(gw * gh)
    np.add.at(total, cell[keep], z[keep])
    np.add.at(count, cell[keep], 1.0)
    grid = np.full(gw * gh, np.nan)
    has = count > 0
    grid[has] = total[has] / count[has]
    grid = grid.reshape(gh, gw)
    out[:] = np.kron(grid, np.ones((CELL_PX, CELL_PX)))[:h, :w]
    return out, used


def exhausted_depth(
    chain: Chain,
    chains: list[Chain],
    keyframes: dict[int, ChainKeyframe],
    index: int,  # the next window's shared keyframe
    min_pixels: int,
    depth: np.ndarray,  # [h, w] its carried depth (owner submap units)
    confidence: np.ndarray | None,  # [h, w]
    unlinked: bool = False,  # the window encoded with ``depth`` could not link its own depth to it
) -> tuple[np.ndarray, np.ndarray | None]:
    """The shared depth handed to the next mono window: ``depth`` unless it measures nothing (a
    placeholder plane or too few pixels) or the window could not link to it (``unlinked``), then the
    rendered depth where that has ``min_pixels``, with the carried-depth confidence
    (:data:`PROPAGATED_CONFIDENCE`). An unlinked carried depth keeps its pixels (and confidence) and
    the rendered depth fills the rest: a sliver at the edge a turn leaves is gone from the window's
    other frames, so the window's own depth has no pixel in common with it (docs/results.md,
    "Two-view windows that break a mono chain, session 15")."""
    if not chain.encodings:
        return depth, confidence
    exhausted = unmeasured(depth, min_pixels)
    if not exhausted and not unlinked:
        return depth, confidence
    K = chain.encodings[-1].intrinsics.K
    rendered, n = rendered_depth(chain, chains, keyframes, index, K, depth.shape)
    has = np.isfinite(rendered)
    why = "exhausted" if exhausted else "unlinked"
    log.info("keyframe %d: carried depth %s; %d pixels rendered from %d keyframes", index, why, has.sum(), n)
    if has.sum() < min_pixels:
        return depth, confidence
    conf = np.where(has, PROPAGATED_CONFIDENCE, 0.0).astype(np.float32)
    if not exhausted:  # the carried sliver stays, the rendered depth fills the rest
        own = np.isfinite(depth) & (depth > 0)
        rendered = np.where(own, depth, rendered).astype(np.float32)
        own_conf = PROPAGATED_CONFIDENCE if confidence is None else confidence
        conf = np.where(own, own_conf, conf).astype(np.float32)
    return rendered, conf


def encode_with_world_depth(
    encoder,  # the mono encoder (``encode(frames, shared_depth=, shared_confidence=)``)
    frames: list,  # the window's keyframes; ``frames[0]`` is the shared frame
    chain: Chain,
    chains: list[Chain],
    keyframes: dict[int, ChainKeyframe],
    depth: np.ndarray,  # [h, w] the shared frame's carried depth (owner submap units)
    confidence: np.ndarray | None,  # [h, w]
    min_pixels: int,  # encoder.min_inliers
    unlinked: bool,  # encoder.mono_world_depth_unlinked
):  # -> SubmapEncoding
    """A mono window encoded against its shared depth, or against the rendered depth where the carried
    one measures nothing (:func:`exhausted_depth`); ``unlinked``: a window whose own depth could not link
    to the carried depth (``meta["unlinked"]``: a sliver at a turn's edge) is encoded again with the
    rendered depth filling the rest. A window encoded against rendered depth says so
    (``meta["world_depth"]``): its frame 0 speaks the earlier geometry in the previous submap's units, and
    the graph's scale link of that submap reads 1."""
    args = (chain, chains, keyframes, frames[0].index, min_pixels)
    shared, shared_conf = exhausted_depth(*args, depth, confidence)
    enc = encoder.encode(frames, shared_depth=shared, shared_confidence=shared_conf)
    if unlinked and shared is depth and enc.meta.get("unlinked"):
        filled, filled_conf = exhausted_depth(*args, depth, shared_conf, unlinked=True)
        if filled is not depth:
            shared = filled
            enc = encoder.encode(frames, shared_depth=filled, shared_confidence=filled_conf)
    if shared is not depth:
        enc.meta["world_depth"] = True
    return enc
