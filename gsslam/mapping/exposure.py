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

Colours are premultiplied by the rendered alpha, so the bias is too (``exp(a) * C + b * alpha``): a
pixel the map does not cover stays black whatever the exposure. An exposure is fitted only where the
map covers its keyframe (alpha > ``COVERED``) and against the render held fixed (:func:`exposed`): a
young map's partly transparent Gaussians render too dark everywhere, and a gain fitted through them
would brighten the render instead of the opacities growing (the map then covered less of its views;
docs/results.md, "Exposure and the map's error, session 8"). A frame that is not (yet) a keyframe is
rendered through the nearest keyframe's exposure (registration, a new keyframe's pose refinement and
its starting exposure), and registration compares the render with the image brought back to the
map's exposure (:func:`unapply`).
"""

from __future__ import annotations

import torch


def identity(device: torch.device | str = "cpu") -> torch.Tensor:  # [2, 3]
    """The identity exposure: zero log gain, zero bias."""
    return torch.zeros(2, 3, device=device)


# pixels whose rendered alpha exceeds this are "covered": the map explains them, an exposure may be fitted
COVERED = 0.9


def apply(
    color: torch.Tensor,  # [H, W, 3] premultiplied by alpha
    exposure: torch.Tensor | None,  # [2, 3] (log gain, bias) per channel; None = identity
    alpha: torch.Tensor | None = None,  # [H, W] rendered alpha; None: 1 everywhere
) -> torch.Tensor:  # [H, W, 3]
    """``exp(a) * color + b * alpha``, differentiable w.r.t. all three."""
    if exposure is None:
        return color
    bias = exposure[1] if alpha is None else exposure[1] * alpha[..., None]
    return color * torch.exp(exposure[0]) + bias


def unapply(
    image: torch.Tensor,  # [H, W, 3] an observed image
    exposure: torch.Tensor | None,  # [2, 3]
) -> torch.Tensor:  # [H, W, 3]
    """The image as the map's exposure (the identity) would see it: ``(image - b) / exp(a)``."""
    if exposure is None:
        return image
    return (image - exposure[1]) * torch.exp(-exposure[0])


def exposed(
    color: torch.Tensor,  # [H, W, 3] premultiplied render
    alpha: torch.Tensor,  # [H, W]
    exposure: torch.Tensor | None,  # [2, 3]; trainable when it requires grad
    image: torch.Tensor,  # [H, W, 3] the keyframe's image
) -> tuple[torch.Tensor, torch.Tensor | None]:  # ([H, W, 3], scalar or None)
    """The render through ``exposure`` for the map's loss, and the exposure's own fitting loss.

    The map's render goes through the exposure held fixed; the exposure is fitted by its own L1 on the
    covered pixels (alpha > :data:`COVERED`) against the render held fixed, so neither stands in for the
    other (module docstring). The fitting loss is None when the exposure is not trained (or None).
    """
    if exposure is None:
        return color, None
    if not exposure.requires_grad:
        return apply(color, exposure, alpha), None
    covered = alpha.detach() > COVERED
    fit = apply(color.detach(), exposure, alpha.detach())
    loss = (fit - image).abs()[covered].mean() if bool(covered.any()) else exposure.sum() * 0.0
    return apply(color, exposure.detach(), alpha), loss


def regularizer(exposure: torch.Tensor) -> torch.Tensor:  # [2, 3] -> scalar
    """``sum(a^2) + sum(b^2)``: zero at the identity."""
    return (exposure**2).sum()


def nearest_exposure(index: int, exposures: dict[int, torch.Tensor]) -> torch.Tensor | None:
    """The exposure of the keyframe nearest to frame ``index`` (ties: the earlier one); None if none."""
    if not exposures:
        return None
    best = min(exposures, key=lambda k: (abs(k - index), k))
    return exposures[best]
