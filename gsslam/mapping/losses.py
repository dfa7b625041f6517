"""Mapping losses (SING3R-SLAM window optimization, GaussianFlow flow supervision).

The SSIM term uses ``gsslam.imaging.ssim_map`` (the metric's implementation, full-size map).

Every function is pure torch, differentiable, and takes an optional ``mask`` [H, W] (bool or float
weights) that restricts the average to supervised pixels. An empty mask gives a zero loss that still
belongs to the graph, so callers can always add the result.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from gsslam.imaging import ssim_map


def _masked_mean(x: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    """Mean of ``x`` [H, W] or [H, W, C] over ``mask`` [H, W] (weights); 0 when the mask is empty."""
    if mask is None:
        return x.mean()
    w = mask.to(x.dtype)
    if x.dim() == w.dim() + 1:
        w = w[..., None].expand_as(x)
    den = w.sum()
    return (x * w).sum() / den.clamp_min(1.0) if den > 0 else (x * 0.0).sum()


def l1(a: torch.Tensor, b: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """Mean absolute difference; a, b [H, W(, C)]."""
    return _masked_mean((a - b).abs(), mask)


def psnr(a: torch.Tensor, b: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """PSNR in dB of images in [0, 1]; a, b [H, W, 3]."""
    mse = _masked_mean((a - b) ** 2, mask)
    return -10.0 * torch.log10(mse.clamp_min(1e-10))


def color_loss(
    render: torch.Tensor,  # [H, W, 3]
    target: torch.Tensor,  # [H, W, 3]
    lambda_ssim: float = 0.2,
    mask: torch.Tensor | None = None,  # [H, W]
) -> torch.Tensor:
    """``(1 - lambda_ssim) * L1 + lambda_ssim * (1 - SSIM)`` (3DGS / SING3R colour term)."""
    loss = (1.0 - lambda_ssim) * l1(render, target, mask)
    if lambda_ssim > 0:
        loss = loss + lambda_ssim * _masked_mean(1.0 - ssim_map(render, target).mean(-1), mask)
    return loss


def inverse_depth_l1(
    depth: torch.Tensor,  # [H, W] rendered depth
    target: torch.Tensor,  # [H, W] measured / predicted depth, NaN or <= 0 = unknown
    mask: torch.Tensor | None = None,  # [H, W]
    min_depth: float = 1e-3,
    weight: torch.Tensor | None = None,  # [H, W] per-pixel confidence in [0, 1]
    unit: float = 1.0,
) -> torch.Tensor:
    """``mean unit * |1/d - 1/d*|`` (x ``weight``) over pixels where both depths are positive (and ``mask``).

    ``unit``: a depth (e.g. the target's median) that makes the term scale-free, so a monocular map's
    arbitrary units do not change its weight. ``weight`` multiplies each pixel's residual; the mean
    stays over the valid pixels, so low-confidence depth pulls less instead of being re-normalized.
    """
    ok = torch.isfinite(target) & (target > min_depth) & (depth > min_depth)
    if mask is not None:
        ok = ok & (mask > 0)
    t = torch.where(ok, target, torch.ones_like(target))
    d = torch.where(ok, depth, torch.ones_like(depth))
    r = unit * (1.0 / d - 1.0 / t).abs()
    if weight is not None:
        r = r * weight
    return _masked_mean(r, ok)


def normals_from_depth(depth: torch.Tensor, K: torch.Tensor) -> torch.Tensor:
    """Camera-frame unit normals [H, W, 3] from a depth map [H, W] and intrinsics K [3, 3].

    Back-projects every pixel, takes central differences of the point map along u and v and
    crosses them; the normal is oriented towards the camera (n_z < 0). Border pixels repeat
    their neighbours.
    """
    h, w = depth.shape
    v, u = torch.meshgrid(
        torch.arange(h, device=depth.device, dtype=depth.dtype),
        torch.arange(w, device=depth.device, dtype=depth.dtype),
        indexing="ij",
    )
    X = torch.stack([(u - K[0, 2]) / K[0, 0] * depth, (v - K[1, 2]) / K[1, 1] * depth, depth], dim=-1)
    Xp = F.pad(X.permute(2, 0, 1)[None], [1, 1, 1, 1], mode="replicate")[0].permute(1, 2, 0)
    du = Xp[1:-1, 2:] - Xp[1:-1, :-2]
    dv = Xp[2:, 1:-1] - Xp[:-2, 1:-1]
    n = torch.cross(du, dv, dim=-1)
    n = n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    return torch.where(n[..., 2:3] > 0, -n, n)


def depth_normal_consistency(
    depth: torch.Tensor,  # [H, W] rendered depth
    normal: torch.Tensor,  # [H, W, 3] rendered normal (camera frame)
    K: torch.Tensor,  # [3, 3]
    mask: torch.Tensor | None = None,  # [H, W]
) -> torch.Tensor:
    """``mean (1 - |<n_depth, n_rendered>|)``: rendered normals agree with the rendered depth's surface."""
    nd = normals_from_depth(depth, K)
    nr = normal / normal.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    ok = (depth > 1e-3) & (normal.norm(dim=-1) > 1e-6)
    if mask is not None:
        ok = ok & (mask > 0)
    return _masked_mean(1.0 - (nd * nr).sum(-1).abs(), ok)


def scale_regularizer(log_scales: torch.Tensor) -> torch.Tensor:  # [N, 3]
    """Isotropy term ``mean_n mean_k |s_nk - mean_k s_nk|`` on linear scales (0 for spheres)."""
    if log_scales.shape[0] == 0:
        return log_scales.sum() * 0.0
    s = torch.exp(log_scales)
    return (s - s.mean(dim=1, keepdim=True)).abs().mean()


def scale_invariant_depth(
    depth: torch.Tensor,  # [H, W]
    target: torch.Tensor,  # [H, W], NaN or <= 0 = unknown
    mask: torch.Tensor | None = None,  # [H, W]
) -> torch.Tensor:
    """L1 between the two depth maps each divided by its median over the common valid pixels.

    Invariant to a global scale of either input (monocular point maps have an arbitrary scale).
    """
    ok = torch.isfinite(target) & (target > 1e-3) & (depth > 1e-3)
    if mask is not None:
        ok = ok & (mask > 0)
    if int(ok.sum()) < 2:
        return depth.sum() * 0.0
    d, t = depth[ok], target[ok]
    return (d / d.detach().median() - t / t.median()).abs().mean()


def robust_flow_nll(
    residual: torch.Tensor,  # [N, 2] pixels
    sigma: float = 1.0,
    inlier_prior: float = 0.9,
    outlier_range: float = 50.0,
) -> torch.Tensor:
    """Per-residual negative log-likelihood under a Gaussian-inlier / uniform-outlier mixture -> [N].

    ``p(r) = pi N(r; 0, sigma^2 I_2) + (1 - pi) / A`` with ``A = outlier_range^2`` (px^2). The value
    is shifted by ``-log p(0)`` so a perfect match costs 0; it saturates at
    ``log(p(0) * A / (1 - pi))`` for outliers, whose gradient vanishes.
    """
    r2 = (residual**2).sum(-1)
    log_in = math.log(inlier_prior) - math.log(2 * math.pi * sigma**2) - 0.5 * r2 / sigma**2
    log_out = math.log(1.0 - inlier_prior) - 2.0 * math.log(outlier_range)
    log_p = torch.logaddexp(log_in, torch.full_like(log_in, log_out))
    log_p0 = math.log(inlier_prior / (2 * math.pi * sigma**2) + (1.0 - inlier_prior) / outlier_range**2)
    return log_p0 - log_p


def sample_image(img: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """Bilinear lookup of ``img`` [H, W, C] at pixel coordinates ``uv`` [N, 2] -> [N, C] (border clamp)."""
    h, w = img.shape[:2]
    gx = (uv[:, 0] + 0.5) / w * 2 - 1
    gy = (uv[:, 1] + 0.5) / h * 2 - 1
    grid = torch.stack([gx, gy], dim=-1)[None, None]
    out = F.grid_sample(
        img.permute(2, 0, 1)[None], grid, mode="bilinear", padding_mode="border", align_corners=False
    )
    return out[0, :, 0].T


def flow_residuals(
    uv_a: torch.Tensor,  # [N, 2] Gaussian centres projected in frame a (mapper pixels)
    uv_b: torch.Tensor,  # [N, 2] the same Gaussians projected in frame b
    flow: torch.Tensor,  # [H, W, 2] measured flow a -> b at mapper resolution
    valid: torch.Tensor,  # [H, W] bool
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """GaussianFlow: projected Gaussian motion minus measured flow at the Gaussians' pixels in a.

    Returns ``(residual [N, 2], measured flow [N, 2], usable [N] bool)``; a Gaussian is usable when
    it projects inside frame a on a pixel whose flow is valid (nearest pixel).
    """
    h, w = flow.shape[:2]
    inside = (uv_a[:, 0] > -0.5) & (uv_a[:, 0] < w - 0.5) & (uv_a[:, 1] > -0.5) & (uv_a[:, 1] < h - 0.5)
    iu = uv_a[:, 0].detach().round().long().clamp(0, w - 1)
    iv = uv_a[:, 1].detach().round().long().clamp(0, h - 1)
    usable = inside & valid[iv, iu]
    f = sample_image(flow, uv_a.detach())
    return (uv_b - uv_a) - f, f, usable


def normalized_flow_error(residual: torch.Tensor, flow: torch.Tensor, eps_px: float = 1.0) -> torch.Tensor:
    """Scale-invariant per-Gaussian error ``|r| / (|f| + eps)``: residual relative to the motion -> [N]."""
    return residual.norm(dim=-1) / (flow.norm(dim=-1) + eps_px)


def flow_loss(
    uv_a: torch.Tensor,  # [N, 2]
    uv_b: torch.Tensor,  # [N, 2]
    flow: torch.Tensor,  # [H, W, 2]
    valid: torch.Tensor,  # [H, W]
    weight: torch.Tensor | None = None,  # [N] e.g. visibility in frame a
    sigma: float = 1.0,
    inlier_prior: float = 0.9,
    outlier_range: float = 50.0,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Mean robust NLL of :func:`flow_residuals` over usable Gaussians.

    Returns ``(loss, normalized error [N] (NaN where unusable), usable [N])``.
    """
    r, f, usable = flow_residuals(uv_a, uv_b, flow, valid)
    w = usable.to(r.dtype) if weight is None else usable.to(r.dtype) * weight
    nll = robust_flow_nll(r, sigma, inlier_prior, outlier_range)
    loss = (nll * w).sum() / w.sum().clamp_min(1.0)
    err = torch.where(
        usable & (w > 0), normalized_flow_error(r.detach(), f), torch.full_like(w, float("nan"))
    )
    return loss, err, usable & (w > 0)
