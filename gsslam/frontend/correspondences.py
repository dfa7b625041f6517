"""Flow correspondences between two keyframes for the graph (GaussianFlow's flow factors).

Pixels are sampled where the flow is valid (forward-backward consistent, target inside the
image) with spatial stratification: the image is cut into a grid of cells and the samples are
spread over the cells round-robin, so that textured corners do not take all the budget.
"""

from __future__ import annotations

import numpy as np

from gsslam.errors import GsslamError
from gsslam.types import Correspondences, Frame

GRID_CELLS = 16  # cells along the longer image side
CANDIDATES_PER_POINT = 16  # candidate pixels kept per requested sample before stratification


class CorrespondenceError(GsslamError):
    """Flow, mask and depth do not fit together."""


def _sample_depth(depth: np.ndarray, uv: np.ndarray, width: int, height: int) -> np.ndarray:
    """Nearest-neighbour depth at full-resolution pixels ``uv`` [N, 2]; depth may be at lower res."""
    dh, dw = depth.shape
    u = np.clip(np.floor((uv[:, 0] + 0.5) * dw / width).astype(int), 0, dw - 1)
    v = np.clip(np.floor((uv[:, 1] + 0.5) * dh / height).astype(int), 0, dh - 1)
    return depth[v, u].astype(np.float64)


def stratified_indices(
    ok: np.ndarray, max_points: int, rng: np.random.Generator, cells: int = GRID_CELLS
) -> np.ndarray:  # ok [H, W] bool -> flat indices [<= max_points]
    """Random flat indices of ``ok`` pixels spread evenly over a grid of cells."""
    H, W = ok.shape
    idx = np.flatnonzero(ok.reshape(-1))
    if len(idx) <= max_points:
        return idx
    idx = rng.permutation(idx)
    v, u = np.divmod(idx, W)
    step = max(H, W) / cells
    cell = (v / step).astype(np.int64) * (cells + 1) + (u / step).astype(np.int64)
    order = np.argsort(cell, kind="stable")
    sorted_cell = cell[order]
    starts = np.r_[0, np.flatnonzero(np.diff(sorted_cell)) + 1]
    counts = np.diff(np.r_[starts, len(order)])
    rank = np.empty(len(idx), dtype=np.int64)
    rank[order] = np.arange(len(order)) - np.repeat(starts, counts)  # position within its cell
    pick = np.argsort(rank, kind="stable")[:max_points]
    return idx[pick]


def correspondences_from_flow(
    src: Frame,
    tgt: Frame,
    flow: np.ndarray,  # [H, W, 2] src -> tgt, full resolution px
    valid: np.ndarray,  # [H, W] bool
    depth_src: np.ndarray | None,  # [H, W] (or lower resolution) source depth in submap units
    max_points: int,
    rng: np.random.Generator,
    fb_error: np.ndarray | None = None,  # [H, W] forward-backward error px, for soft weights
) -> Correspondences:
    """Sample up to ``max_points`` flow matches ``src -> tgt`` (full-resolution pixels).

    ``depth_src`` NaN/<=0 gives NaN depth (the match still constrains the relative pose through
    its epipolar line). Weights are 1, or ``exp(-(fb_error / 2 px)^2)`` when ``fb_error`` is given.
    """
    H, W = src.image.shape[:2]
    if flow.shape != (H, W, 2):
        raise CorrespondenceError(
            f"flow must be [{H}, {W}, 2] (full resolution of frame {src.index}), got {flow.shape}"
        )
    if valid.shape != (H, W):
        raise CorrespondenceError(f"valid must be [{H}, {W}], got {valid.shape}")
    if max_points < 0:
        raise CorrespondenceError(f"max_points must be >= 0, got {max_points}")
    # Candidates on a grid of every ``stride``-th pixel (random offset) while it still holds
    # CANDIDATES_PER_POINT candidates per requested point: dense flow does not change at the
    # scale of a few pixels, and the stratified sampling costs ~stride^2 less.
    stride = max(1, int(np.sqrt(np.count_nonzero(valid) / max(CANDIDATES_PER_POINT * max_points, 1))))
    ou, ov = rng.integers(stride, size=2) if stride > 1 else (0, 0)
    fs = flow[ov::stride, ou::stride]
    ok = valid[ov::stride, ou::stride] & np.isfinite(fs).all(-1)
    grid_v, grid_u = np.mgrid[ov:H:stride, ou:W:stride]
    tu, tv = grid_u + fs[..., 0], grid_v + fs[..., 1]
    with np.errstate(invalid="ignore"):
        ok &= (tu >= 0) & (tu <= W - 1) & (tv >= 0) & (tv <= H - 1)
    sub = stratified_indices(ok, max_points, rng)
    v_sub, u_sub = np.divmod(sub, ok.shape[1])
    u, v = ou + stride * u_sub, ov + stride * v_sub
    idx = v * W + u  # flat indices at full resolution
    uv_src = np.stack([u, v], 1).astype(np.float64)
    uv_tgt = uv_src + flow.reshape(-1, 2)[idx].astype(np.float64)
    if depth_src is None:
        depth = np.full(len(idx), np.nan)
    else:
        depth = _sample_depth(np.asarray(depth_src), uv_src, W, H)
        depth[~(depth > 0)] = np.nan
    if fb_error is None:
        weight = np.ones(len(idx))
    else:
        e = np.nan_to_num(fb_error.reshape(-1)[idx].astype(np.float64), nan=np.inf)
        weight = np.exp(-((e / 2.0) ** 2))
    return Correspondences(src.index, tgt.index, uv_src, uv_tgt, depth, weight)
