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


def _symmetric_index(n: int, r: int, device) -> torch.Tensor:  # [n + 2r] source index per padded position
    i = torch.arange(-r, n + r, device=device)
    i = torch.where(i < 0, -i - 1, i)
    return torch.where(i >= n, 2 * n - i - 1, i)


def ssim_map(
    a: torch.Tensor,  # [H, W, C] (C channels, e.g. 3), values in [0, data_range]
    b: torch.Tensor,  # [H, W, C]
    data_range: float = 1.0,
    sigma: float = SIGMA,
) -> torch.Tensor:  # [H, W, C] local SSIM
    """Per-pixel, per-channel SSIM with a separable Gaussian window and symmetric border padding."""
    if a.shape != b.shape or a.dim() != 3:
        raise ValueError(
            f"ssim_map needs two [H, W, C] images of one shape, got {tuple(a.shape)}, {tuple(b.shape)}"
        )
    w = gaussian_window(sigma, a.dtype, a.device)
    r = len(w) // 2
    h, wd, c = a.shape
    if min(h, wd) < len(w):
        raise ValueError(f"SSIM needs images of at least {len(w)}x{len(w)} pixels, got {h}x{wd}")
    x, y = a.permute(2, 0, 1), b.permute(2, 0, 1)
    stack = torch.cat([x, y, x * x, y * y, x * y])[None]  # [1, 5C, H, W]
    n = stack.shape[1]
    stack = stack.index_select(2, _symmetric_index(h, r, a.device))
    stack = F.conv2d(stack, w.view(1, 1, -1, 1).expand(n, 1, -1, 1), groups=n)
    # symmetric padding along the width by slices (a gather along the last dim is ~4x slower on CPU)
    stack = torch.cat([stack[..., :r].flip(3), stack, stack[..., wd - r :].flip(3)], dim=3)
    mu_x, mu_y, xx, yy, xy = F.conv2d(stack, w.view(1, 1, 1, -1).expand(n, 1, 1, -1), groups=n)[0].split(c)
    var_x, var_y, cov = xx - mu_x**2, yy - mu_y**2, xy - mu_x * mu_y
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    s = ((2 * mu_x * mu_y + c1) * (2 * cov + c2)) / ((mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2))
    return s.permute(1, 2, 0)


def ssim(a: torch.Tensor, b: torch.Tensor, data_range: float = 1.0) -> torch.Tensor:  # a, b [H, W, C] -> []
    """Mean SSIM over the interior (windows inside the image) and the channels; 1 for identical images."""
    return ssim_map(a, b, data_range)[RADIUS:-RADIUS, RADIUS:-RADIUS].mean()
