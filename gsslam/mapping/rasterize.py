"""Differentiable 3D Gaussian rasterizer: :func:`render` and its output :class:`RenderOutput`.

Standard 3DGS maths (EWA splatting, front-to-back alpha compositing sorted by depth); see
docs/rasterizer.md for the exact rules. Gaussian rotations are quaternions in (w, x, y, z) order.

Backends: ``"torch"`` (the pure-torch reference, :mod:`gsslam.mapping.rasterize_reference`),
``"c"`` (compiled CPU compositor with a hand-written backward, :mod:`gsslam.mapping.rasterize_cpu`;
``"fast"`` is its former name), ``"gsplat"`` (CUDA, optional extra ``cuda``) and ``"auto"`` (gsplat
for CUDA tensors when installed, else c when its kernel is built, else torch). An explicitly named
backend that cannot run raises :class:`RasterizerUnavailableError`; :func:`resolve_backend` tells
beforehand which backend a request will use.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import torch
from torch import Tensor

from gsslam.mapping.projection import LOW_PASS, RasterizeError, check_inputs, in_view, project_gaussians
from gsslam.mapping.rasterize_reference import composite_reference

_log = logging.getLogger(__name__)

ALPHA_EPS = 1e-6  # depth is divided by alpha only where alpha > this (else 0)
BACKENDS = ("auto", "c", "torch", "gsplat", "fast")  # "fast": the former name of "c"
_USED: set[str] = set()  # the backends that rendered in this process (for a run's provenance)


def backends_used() -> list[str]:
    """The backends (``c``, ``torch``, ``gsplat``) that :func:`render` ran so far in this process."""
    return sorted(_USED)


class RasterizerUnavailableError(RasterizeError):
    """The requested rasterizer backend cannot run here (kernel not built, gsplat missing, wrong device)."""


def resolve_backend(requested: str, device: torch.device | str) -> str:
    """The backend (``"c"``, ``"torch"`` or ``"gsplat"``) that ``requested`` uses on ``device``.

    ``"auto"`` never fails: gsplat on CUDA when installed, else c on the CPU when its kernel is
    available (else torch, after one warning from :mod:`gsslam.mapping.rasterize_cpu`). A backend
    named explicitly that cannot run raises :class:`RasterizerUnavailableError` saying how to fix it.
    """
    if requested not in BACKENDS:
        raise RasterizeError(f"unknown rasterizer backend {requested!r}; choose one of {', '.join(BACKENDS)}")
    dev = torch.device(device).type
    if requested == "torch":
        return "torch"
    if requested == "gsplat" or (requested == "auto" and dev == "cuda"):
        if dev == "cuda" and _gsplat_available():
            return "gsplat"
        if requested == "auto":
            return "torch"
        if dev != "cuda":
            raise RasterizerUnavailableError(
                "the gsplat rasterizer needs CUDA tensors; set mapper.device=cuda, or mapper.rasterizer=auto"
            )
        raise RasterizerUnavailableError(
            "the gsplat rasterizer needs the optional 'cuda' extra: pip install 'gsslam[cuda]' (gsplat)"
        )
    if dev != "cpu":  # "c" / "fast" / "auto" on a device other than cpu and cuda
        if requested == "auto":
            return "torch"
        raise RasterizerUnavailableError(
            f"the C rasterizer runs on the CPU, not on {dev}; set mapper.device=cpu or mapper.rasterizer=auto"
        )
    from gsslam.mapping import rasterize_cpu

    reason = rasterize_cpu.unavailable_reason()
    if reason is None:
        return "c"
    if requested == "auto":
        _warn_fallback(reason)
        return "torch"
    raise RasterizerUnavailableError(
        f"the compiled C rasterizer is unavailable: {reason}. Fix: reinstall with a C compiler present "
        "(`pip install .` builds the kernel), or put a C compiler on PATH (`cc`, or set CC) for the "
        "first-use build; or choose mapper.rasterizer=auto (uses torch when c is missing) or torch"
    )


@dataclass
class RenderOutput:
    color: Tensor  # [H, W, 3] blended colour + (1 - alpha) * background
    depth: Tensor  # [H, W] expected z-depth: sum(w_i z_i) / alpha where alpha > 1e-6, else 0
    alpha: Tensor  # [H, W] accumulated opacity sum(w_i)
    normal: Tensor  # [H, W, 3] camera-frame sum(w_i n_i) (not normalized; divide by alpha if needed)
    means2d: Tensor  # [N, 2] projected centres (px), differentiable
    cov2d: Tensor  # [N, 2, 2] projected 2D covariances (px^2, incl. the low-pass, 0.3 px^2 by default)
    depths: Tensor  # [N] camera z of the centres
    radii: Tensor  # [N] int pixel radius (0 = not visible)


def render(
    means: Tensor,  # [N, 3] world
    quats: Tensor,  # [N, 4] (w, x, y, z), unnormalized ok
    scales: Tensor,  # [N, 3] linear (positive)
    opacities: Tensor,  # [N] in (0, 1)
    colors: Tensor,  # [N, 3] in [0, 1]
    T_cam_world: Tensor,  # [4, 4]
    K: Tensor,  # [3, 3]
    width: int,
    height: int,
    background: Tensor | None = None,  # [3]
    near: float = 0.01,
    backend: str = "auto",
    cull: bool = False,
    low_pass: float = LOW_PASS,
) -> RenderOutput:
    """Render colour, depth, alpha and normals of a Gaussian map seen from ``T_cam_world``.

    Differentiable w.r.t. every Gaussian parameter and ``T_cam_world`` (gradients flow to whatever
    pose parameterization produced it). Pixel centres are at integer coordinates (OpenCV).

    ``cull``: project and composite only the Gaussians a conservative frustum test keeps
    (:func:`~gsslam.mapping.projection.in_view`; CPU backends). The images, and every gradient, are
    those of the full render; of the per-Gaussian outputs, culled Gaussians get ``radii`` 0 (as
    without culling), ``means2d`` / ``depths`` without gradient and a zero ``cov2d``. The cost of a
    step then follows the Gaussians in view, not the size of the map.

    ``low_pass``: the screen-space dilation (px^2) added to every projected covariance (3DGS: 0.3).
    """
    if backend not in BACKENDS:
        raise RasterizeError(f"unknown rasterizer backend {backend!r}; choose one of {', '.join(BACKENDS)}")
    if backend == "fast":
        backend = "c"
    check_inputs(means, quats, scales, opacities, colors, T_cam_world, K, width, height)
    width, height = int(width), int(height)
    if cull and not means.is_cuda:
        keep, centres, z = in_view(means, scales, T_cam_world, K, width, height, near, low_pass)
        if not bool(keep.all()):
            idx = keep.nonzero()[:, 0]
            sub = render(
                means[idx], quats[idx], scales[idx], opacities[idx], colors[idx], T_cam_world, K,
                width, height, background, near, backend, low_pass=low_pass,
            )  # fmt: skip
            return _expand(sub, idx, centres, z)
    if backend in ("c", "auto") and not means.is_cuda and not K.requires_grad and _c_available(means):
        from gsslam.mapping.rasterize_cpu import project_cpu  # the same projection, in C (its twin above)

        proj = project_cpu(means, quats, scales, T_cam_world, K, width, height, near, low_pass)
    else:
        proj = project_gaussians(means, quats, scales, T_cam_world, K, width, height, near, low_pass)
    if backend == "gsplat" or (backend == "auto" and means.is_cuda and _gsplat_available()):
        _USED.add("gsplat")
        return _render_gsplat(
            proj, means, quats, scales, opacities, colors, T_cam_world, K, width, height, background, near,
            low_pass,
        )  # fmt: skip
    features = torch.cat([colors.to(means.dtype), proj.depths[:, None], proj.normals], dim=-1)  # [N, 7]
    args = (
        proj.means2d,
        proj.conics,
        opacities.to(means.dtype),
        features,
        proj.depths,
        proj.radii,
        width,
        height,
    )
    if backend == "c" and not _c_available(means):
        resolve_backend("c", means.device)  # raises with the reason when the kernel is missing
        raise RasterizerUnavailableError(
            f"the C rasterizer takes float32/float64 CPU tensors, got {means.dtype} on {means.device}"
        )
    if backend == "auto" and not means.is_cuda and not _c_available(means):
        from gsslam.mapping import rasterize_cpu

        if rasterize_cpu.unavailable_reason() is not None:
            _warn_fallback(rasterize_cpu.unavailable_reason())
    if backend == "torch" or (backend == "auto" and not _c_available(means)):
        _USED.add("torch")
        feat, alpha = composite_reference(*args)
    else:
        from gsslam.mapping.rasterize_cpu import composite_cpu

        _USED.add("c")
        feat, alpha = composite_cpu(*args)
    color = feat[..., :3]
    if background is not None:
        color = color + (1.0 - alpha)[..., None] * background.to(color.dtype)
    depth = torch.where(alpha > ALPHA_EPS, feat[..., 3] / alpha.clamp_min(ALPHA_EPS), torch.zeros_like(alpha))
    return RenderOutput(
        color=color,
        depth=depth,
        alpha=alpha,
        normal=feat[..., 4:7],
        means2d=proj.means2d,
        cov2d=proj.cov2d,
        depths=proj.depths,
        radii=proj.radii,
    )


def _expand(
    sub: RenderOutput,
    idx: Tensor,  # [M] int64 indices of the rendered Gaussians among N
    centres: Tensor,  # [N, 2] px, projected centres of all Gaussians (no gradient)
    z: Tensor,  # [N] camera z of all centres (no gradient)
) -> RenderOutput:
    """Per-Gaussian outputs of a render of the Gaussians ``idx``, back at the size of the whole map."""
    n = centres.shape[0]
    dt = sub.cov2d.dtype
    return RenderOutput(
        color=sub.color,
        depth=sub.depth,
        alpha=sub.alpha,
        normal=sub.normal,
        means2d=centres.to(sub.means2d.dtype).index_put((idx,), sub.means2d),
        cov2d=torch.zeros(n, 2, 2, dtype=dt, device=centres.device).index_put((idx,), sub.cov2d),
        depths=z.to(sub.depths.dtype).index_put((idx,), sub.depths),
        radii=torch.zeros(n, dtype=sub.radii.dtype, device=centres.device).index_put((idx,), sub.radii),
    )


def _render_gsplat(
    proj,
    means,
    quats,
    scales,
    opacities,
    colors,
    T_cam_world,
    K,
    width,
    height,
    background,
    near,
    low_pass=LOW_PASS,
) -> RenderOutput:
    """CUDA path: gsplat.rasterization for the images; the per-Gaussian outputs come from our projection.

    gsplat puts pixel centres at +0.5, so the principal point is shifted by half a pixel. Normals ride
    along as three extra colour channels; "RGB+ED" gives the alpha-normalized expected depth.
    """
    try:
        import gsplat
    except ImportError:
        raise RasterizerUnavailableError(
            "backend='gsplat' needs the optional 'cuda' extra: pip install 'gsslam[cuda]' (gsplat)"
        ) from None
    if not means.is_cuda:
        raise RasterizerUnavailableError(
            "backend='gsplat' needs CUDA tensors; move the inputs to the GPU or use 'c'"
        )
    dtype = means.dtype
    Kg = K.to(dtype).clone()
    Kg[0, 2] = Kg[0, 2] + 0.5
    Kg[1, 2] = Kg[1, 2] + 0.5
    feats = torch.cat([colors.to(dtype), proj.normals], dim=-1)  # [N, 6]
    img, alpha, _ = gsplat.rasterization(
        means,
        quats,
        scales,
        opacities,
        feats,
        T_cam_world.to(dtype)[None],
        Kg[None],
        width,
        height,
        near_plane=near,
        eps2d=low_pass,
        packed=False,
        render_mode="RGB+ED",
        rasterize_mode="classic",
    )
    img, alpha = img[0], alpha[0, ..., 0]  # [H, W, 7], [H, W]
    color = img[..., :3]
    if background is not None:
        color = color + (1.0 - alpha)[..., None] * background.to(color.dtype)
    depth = torch.where(alpha > ALPHA_EPS, img[..., 6], torch.zeros_like(alpha))
    return RenderOutput(
        color=color,
        depth=depth,
        alpha=alpha,
        normal=img[..., 3:6],
        means2d=proj.means2d,
        cov2d=proj.cov2d,
        depths=proj.depths,
        radii=proj.radii,
    )


def _gsplat_available() -> bool:
    try:
        import gsplat  # noqa: F401
    except ImportError:
        return False
    return True


_warned = False


def _warn_fallback(reason: str) -> None:
    """One WARNING per process when ``auto`` cannot use the compiled kernel on the CPU."""
    global _warned
    if not _warned:
        _warned = True
        _log.warning(
            "compiled C rasterizer unavailable (%s); using the slower pure-torch reference "
            "(same results; mapper.rasterizer=c makes this an error)",
            reason,
        )


def _c_available(means: Tensor) -> bool:
    from gsslam.mapping import rasterize_cpu

    return rasterize_cpu.available(means)
