"""Pure-torch reference compositor: the twin every fast rasterizer path is tested against.

It lists every (pixel, Gaussian) pair inside each Gaussian's bounding square, sorts the pairs by
pixel and depth, lays them out as a padded ``[P, Kmax]`` table and composites front to back with
``torch.cumprod``; plain autograd gives the gradients. Simple and exact, but memory- and time-hungry:
use it for tests and as the fallback when no compiled path is available.

Rules (shared by all backends, see docs/rasterizer.md): a Gaussian touches pixel ``p`` (centre at
integer coordinates) only inside its 3-sigma ellipse (``0.5 d^T Sigma2d^-1 d <= 4.5``);
``alpha = min(0.99, o exp(-0.5 d^T Sigma2d^-1 d))``; pairs with ``alpha < 1/255`` are skipped;
compositing stops (excluding that Gaussian) at the first Gaussian that would bring the
transmittance below 1e-4. Ties in depth are broken by Gaussian index.
"""

from __future__ import annotations

import torch
from torch import Tensor

from gsslam.mapping.projection import ALPHA_MAX, ALPHA_MIN, POWER_CUTOFF, T_MIN


def pixel_gaussian_pairs(
    means2d: Tensor,  # [N, 2]
    radii: Tensor,  # [N] int
    width: int,
    height: int,
) -> tuple[Tensor, Tensor]:
    """All (pixel index, Gaussian index) pairs inside each visible Gaussian's bounding square."""
    dev = means2d.device
    with torch.no_grad():
        mu = means2d.detach()
        r = radii.to(mu.dtype)
        x0 = torch.ceil(mu[:, 0] - r).clamp(0, width - 1).to(torch.int64)
        x1 = torch.floor(mu[:, 0] + r).clamp(0, width - 1).to(torch.int64)
        y0 = torch.ceil(mu[:, 1] - r).clamp(0, height - 1).to(torch.int64)
        y1 = torch.floor(mu[:, 1] + r).clamp(0, height - 1).to(torch.int64)
        w = (x1 - x0 + 1).clamp_min(0)
        h = (y1 - y0 + 1).clamp_min(0)
        count = torch.where(radii > 0, w * h, torch.zeros_like(w))
        gid = torch.repeat_interleave(torch.arange(len(count), device=dev), count)
        start = torch.cumsum(count, 0) - count
        local = torch.arange(len(gid), device=dev) - start[gid]
        px = x0[gid] + local % w[gid]
        py = y0[gid] + local // w[gid]
    return py * width + px, gid


def composite_reference(
    means2d: Tensor,  # [N, 2] px
    conics: Tensor,  # [N, 3] (a, b, c) of the inverse 2D covariance
    opacities: Tensor,  # [N]
    features: Tensor,  # [N, F] blended per pixel (colour, depth, normal, ...)
    depths: Tensor,  # [N] sort key (camera z)
    radii: Tensor,  # [N] int, 0 = skip
    width: int,
    height: int,
) -> tuple[Tensor, Tensor]:
    """Front-to-back alpha compositing -> (``sum_i w_i f_i`` [H, W, F], ``sum_i w_i`` [H, W]).

    ``w_i = alpha_i T_i`` are the blending weights; no background is added.
    """
    n, f = features.shape
    P = width * height
    dev, dtype = means2d.device, means2d.dtype
    pix, gid = pixel_gaussian_pairs(means2d, radii, width, height)
    if len(pix) == 0:
        return features.new_zeros(height, width, f) + 0 * features.sum(), means2d.new_zeros(height, width)
    with torch.no_grad():
        order_rank = torch.empty(n, dtype=torch.int64, device=dev)
        order_rank[torch.sort(depths.detach(), stable=True).indices] = torch.arange(n, device=dev)
        key = pix * n + order_rank[gid]
        perm = torch.sort(key).indices
        pix, gid = pix[perm], gid[perm]
        counts = torch.bincount(pix, minlength=P)
        kmax = int(counts.max())
        seg_start = torch.cumsum(counts, 0) - counts
        slot = torch.arange(len(pix), device=dev) - seg_start[pix]

    px = (pix % width).to(dtype)
    py = torch.div(pix, width, rounding_mode="floor").to(dtype)
    dx = px - means2d[gid, 0]
    dy = py - means2d[gid, 1]
    con = conics[gid]
    power = 0.5 * (con[:, 0] * dx * dx + con[:, 2] * dy * dy) + con[:, 1] * dx * dy
    alpha = torch.clamp(opacities[gid] * torch.exp(-power), max=ALPHA_MAX)
    keep = (power <= POWER_CUTOFF) & (alpha >= ALPHA_MIN)
    alpha = torch.where(keep, alpha, torch.zeros_like(alpha))

    table = alpha.new_zeros(P, kmax)
    table = table.index_put((pix, slot), alpha)  # [P, Kmax], 0 = padding / skipped
    one_minus = 1.0 - table
    T_after = torch.cumprod(one_minus, dim=1)  # transmittance after each entry
    T_before = torch.cat([torch.ones_like(T_after[:, :1]), T_after[:, :-1]], dim=1)
    with torch.no_grad():
        alive = T_after >= T_MIN  # a prefix of each row: the early stop
    weights = torch.where(alive, table * T_before, torch.zeros_like(table))  # [P, Kmax]
    w_pairs = weights[pix, slot]  # [M]
    out = torch.zeros(P, f, dtype=features.dtype, device=dev).index_add(
        0, pix, w_pairs[:, None] * features[gid]
    )
    acc = weights.sum(dim=1)
    return out.reshape(height, width, f), acc.reshape(height, width)
