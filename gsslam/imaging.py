"""SSIM (Wang et al. 2004), the one implementation: the mapping loss and the evaluation metric use it.

Convention (the one papers report; what ``skimage.metrics.structural_similarity(gaussian_weights=True,
sigma=1.5, use_sample_covariance=False)``, pytorch_msssim and torchmetrics compute): a Gaussian
window with sigma 1.5 truncated at 3.5 sigma (11 x 11), K1 = 0.01, K2 = 0.03, population
(co)variances, per channel. The map is full size with symmetric padding (edge pixel repeated) so a
loss can weight every pixel; the *score* ``ssim`` averages the interior only (a 5-pixel border
left out, where windows would reach the padding) and the channels.

Pure torch and differentiable; depends on nothing else in gsslam (eval and mapping both import it).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

SIGMA = 1.5
TRUNCATE = 3.5
RADIUS = int(TRUNCATE * SIGMA + 0.5)  # 5: an 11 x 11 window


def gaussian_window(sigma: float = SIGMA, dtype=torch.float64, device=None) -> torch.Tensor:  # [2r+1]
    r = int(TRUNCATE * sigma + 0.5)
    x = torch.arange(-r, r + 1, dtype=dtype, device=device)
    w = torch.exp(-0.5 * (x / sigma) ** 2)
    return w / w.sum()


def ssim_map(
    a: torch.Tensor,  # [H, W, C] (C channels, e.g. 3), values in [0, data_range]
    b: torch.Tensor,  # [H, W, C]
    data_range: float = 1.0,
    sigma: float = SIGMA,
) -> torch.Tensor:  # [H, W, C] local SSIM
    """Per-pixel, per-channel SSIM with a separable Gaussian window and symmetric border padding.

    Differentiable. When only ``a`` needs a gradient (a render against a fixed image, the mapping
    loss) the gradient is hand-written (:class:`_SSIMRender`: three blurred maps instead of autograd
    through fifteen); the values are the same either way.
    """
    if a.shape != b.shape or a.dim() != 3:
        raise ValueError(
            f"ssim_map needs two [H, W, C] images of one shape, got {tuple(a.shape)}, {tuple(b.shape)}"
        )
    w = gaussian_window(sigma, a.dtype, a.device)
    h, wd = a.shape[0], a.shape[1]
    if min(h, wd) < len(w):
        raise ValueError(f"SSIM needs images of at least {len(w)}x{len(w)} pixels, got {h}x{wd}")
    if torch.is_grad_enabled() and a.requires_grad and not b.requires_grad:
        return _SSIMRender.apply(a, b, w, data_range)
    return _ssim_parts(a, b, w, data_range)[0]


def _blur(stack: torch.Tensor, w: torch.Tensor) -> torch.Tensor:  # [1, n, H, W] -> [1, n, H, W]
    """The separable window ``w`` over rows then columns, symmetric padding (edge pixel repeated)."""
    n, h, wd, r = stack.shape[1], stack.shape[2], stack.shape[3], len(w) // 2
    # symmetric padding by slices (edge row repeated; an index_select of the rows is slower on CPU)
    stack = torch.cat([stack[:, :, :r].flip(2), stack, stack[:, :, h - r :].flip(2)], dim=2)
    stack = F.conv2d(stack, w.view(1, 1, -1, 1).expand(n, 1, -1, 1), groups=n)
    # symmetric padding along the width by slices (a gather along the last dim is ~4x slower on CPU)
    stack = torch.cat([stack[..., :r].flip(3), stack, stack[..., wd - r :].flip(3)], dim=3)
    return F.conv2d(stack, w.view(1, 1, 1, -1).expand(n, 1, 1, -1), groups=n)


def _blur_adjoint(g: torch.Tensor, w: torch.Tensor) -> torch.Tensor:  # [1, n, H, W] -> [1, n, H, W]
    """The transpose of :func:`_blur`: ``<_blur(x), g> = <x, _blur_adjoint(g)>`` for every x.

    The window is symmetric, so the transpose of each valid convolution is the full one (zero padding
    2r); the padded rows and columns are then added back onto the pixels they repeat.
    """
    n, h, wd, r = g.shape[1], g.shape[2], g.shape[3], len(w) // 2
    # (explicit zero padding: conv2d's own padding argument is ~1.6x slower on CPU here)
    t = F.conv2d(F.pad(g, (2 * r, 2 * r)), w.view(1, 1, 1, -1).expand(n, 1, 1, -1), groups=n)  # W + 2r wide
    core = t[..., r : r + wd].clone()
    core[..., :r] += t[..., :r].flip(3)
    core[..., wd - r :] += t[..., wd + r :].flip(3)
    t = F.conv2d(F.pad(core, (0, 0, 2 * r, 2 * r)), w.view(1, 1, -1, 1).expand(n, 1, -1, 1), groups=n)
    out = t[:, :, r : r + h].clone()  # [1, n, H, W] from [1, n, H + 2r, W]
    out[:, :, :r] += t[:, :, :r].flip(2)
    out[:, :, h - r :] += t[:, :, h + r :].flip(2)
    return out


def _ssim_parts(a: torch.Tensor, b: torch.Tensor, w: torch.Tensor, data_range: float):
    """SSIM map [H, W, C] and what its gradient needs: ``(s, (mu_x, mu_y, A1, A2, B1, B2))`` [C, H, W]."""
    c = a.shape[2]
    x, y = a.permute(2, 0, 1), b.permute(2, 0, 1)
    mu_x, mu_y, xx, yy, xy = _blur(torch.cat([x, y, x * x, y * y, x * y])[None], w)[0].split(c)
    var_x, var_y, cov = xx - mu_x**2, yy - mu_y**2, xy - mu_x * mu_y
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    A1, A2 = 2 * mu_x * mu_y + c1, 2 * cov + c2
    B1, B2 = mu_x**2 + mu_y**2 + c1, var_x + var_y + c2
    s = (A1 * A2) / (B1 * B2)
    return s.permute(1, 2, 0), (mu_x, mu_y, A1, A2, B1, B2)


class _SSIMRender(torch.autograd.Function):
    """:func:`ssim_map` of ``a`` against a constant ``b``, with the gradient w.r.t. ``a`` by hand.

    With ``s = A1 A2 / (B1 B2)`` (A1 = 2 mu_x mu_y + c1, A2 = 2 cov + c2, B1 = mu_x^2 + mu_y^2 + c1,
    B2 = var_x + var_y + c2) and the blurred moments mu_x = B(x), sxx = B(x^2), sxy = B(xy):
    ds/dmu_x = 2 s (mu_y / A1 - mu_y / A2 - mu_x / B1 + mu_x / B2), ds/dsxx = -s / B2, ds/dsxy = 2 s / A2,
    so dL/dx = B^T(g ds/dmu_x) + 2 x B^T(g ds/dsxx) + y B^T(g ds/dsxy) with B^T :func:`_blur_adjoint`.
    """

    @staticmethod
    def forward(ctx, a, b, w, data_range):
        s, (mu_x, mu_y, A1, A2, B1, B2) = _ssim_parts(a, b, w, data_range)
        ctx.save_for_backward(a, b, w, s, mu_x, mu_y, A1, A2, B1, B2)
        return s

    @staticmethod
    def backward(ctx, g):  # g [H, W, C]
        a, b, w, s, mu_x, mu_y, A1, A2, B1, B2 = ctx.saved_tensors
        c = a.shape[2]
        gs = (g * s).permute(2, 0, 1)  # [C, H, W]
        d_mu = 2 * gs * (mu_y / A1 - mu_y / A2 - mu_x / B1 + mu_x / B2)
        d_xx = -gs / B2
        d_xy = 2 * gs / A2
        t_mu, t_xx, t_xy = _blur_adjoint(torch.cat([d_mu, d_xx, d_xy])[None], w)[0].split(c)
        x, y = a.permute(2, 0, 1), b.permute(2, 0, 1)
        return (t_mu + 2 * x * t_xx + y * t_xy).permute(1, 2, 0), None, None, None


def ssim(a: torch.Tensor, b: torch.Tensor, data_range: float = 1.0) -> torch.Tensor:  # a, b [H, W, C] -> []
    """Mean SSIM over the interior (windows inside the image) and the channels; 1 for identical images."""
    return ssim_map(a, b, data_range)[RADIUS:-RADIUS, RADIUS:-RADIUS].mean()
