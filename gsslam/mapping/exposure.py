"""Per-keyframe exposure: an affine colour change of the render, optimised with the map.

Cameras with auto-exposure (TUM's Kinect: the colour of a surface drifts from frame to frame) cannot
be fitted by one colour per Gaussian. Each keyframe ``k`` therefore carries an exposure ``E_k`` [2, 3]:
row 0 the per-channel log gain ``a``, row 1 the per-channel bias ``b``; the render seen through it is
``exp(a) * colour + b`` (MonoGS / SplaTAM-style affine brightness). The photometric loss compares that
with the keyframe's image; a small L2 term pulls ``E_k`` towards the identity (zeros), and the first
keyframe's exposure stays the identity (the gauge: a common gain of all keyframes is the Gaussians'
colour). Evaluation scores a keyframe through its own exposure and a frame the mapper never saw
through the exposure of the keyframe nearest in frame index (:func:`nearest_exposure`), which uses no
pixel of that frame.
"""

from __future__ import annotations

import torch


def identity(device: torch.device | str = "cpu") -> torch.Tensor:  # [2, 3]
    """The identity exposure: zero log gain, zero bias."""
    return torch.zeros(2, 3, device=device)


def apply(
    color: torch.Tensor,  # [H, W, 3]
    exposure: torch.Tensor | None,  # [2, 3] (log gain, bias) per channel; None = identity
) -> torch.Tensor:  # [H, W, 3]
    """``exp(a) * color + b``, differentiable w.r.t. both."""
    if exposure is None:
        return color
    return color * torch.exp(exposure[0]) + exposure[1]


def regularizer(exposure: torch.Tensor) -> torch.Tensor:  # [2, 3] -> scalar
    """``sum(a^2) + sum(b^2)``: zero at the identity."""
    return (exposure**2).sum()


def nearest_exposure(index: int, exposures: dict[int, torch.Tensor]) -> torch.Tensor | None:
    """The exposure of the keyframe nearest to frame ``index`` (ties: the earlier one); None if none."""
    if not exposures:
        return None
    best = min(exposures, key=lambda k: (abs(k - index), k))
    return exposures[best]
