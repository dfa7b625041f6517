"""The derivative of a render with respect to the camera pose, from one render (the warp of its image).

Moving the camera by a small right perturbation ``delta = (rho, phi)`` (``T_world_cam @ D(delta)``,
:func:`gsslam.mapping.pose.se3_delta_matrix`) moves the surface point seen at pixel ``u`` (rendered
depth ``z``, camera point ``X = z K^-1 [u, 1]``) to the camera point ``X' = X - rho + [X]x phi`` and
the pixel ``u' = pi(X')``. The new render at ``u'`` is the old render at ``u`` (the map is rigid), so

    d R(u) / d delta = -grad R(u) . d u' / d delta                      (colour, alpha)
    d log Z(u) / d delta = (d X'_z / d delta) / z - grad log Z(u) . d u' / d delta   (depth)

with image gradients by (five-point) central differences. This is direct image alignment's Jacobian (DVO, DSO)
applied to the render: one render per Gauss-Newton step instead of 1 + 2 x 6 for central
differences of renders (docs/mapping.md, "Registration cost").

Which depth moves a pixel: the image's slope is largest at occlusion edges, and an edge moves with the
*occluder*. The rendered depth there is a blend of the occluder's and the background's (alpha
compositing over the soft edge of the front Gaussians), farther than the occluder, so a translation
moved the edge too little: the translation columns were 20-35 % short at edges (all pixels: colour
13-23 %, log depth ~50 %; rotations move a pixel independently of its depth and were not). The pixel
motion (``d u'/d delta``) therefore takes the nearest rendered depth within ``FRONT_WINDOW`` pixels
(the span of the gradient's stencil), :func:`front_depth`; the depth residual's own term
``d X'_z / d delta / z`` keeps the pixel's depth. Measured on teddy against central differences of renders
(docs/results.md, "Registration Jacobian, session 7"): every column 4-7 % short (the five-point slope of a
120 px render), cosines 0.98-0.99.
"""

from __future__ import annotations

import dataclasses

import torch

from gsslam.types import CameraIntrinsics

FRONT_WINDOW = 5  # pixels: the nearest surface within this square moves a pixel (the 5-point stencil's span)
SUBPIXEL = 0.1  # pixels: the principal-point shift of the renders that give the render's exact slopes


def image_gradient(img: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:  # [H, W, ...] -> (d/du, d/dv)
    """Derivatives along the image's columns (u) and rows (v): five-point central differences (less
    smoothing than three-point ones: the render's own slope is what the pose moves), three-point next
    to the border and one-sided on it. Images narrower than 5 pixels are not supported."""
    return _derivative(img.transpose(0, 1)).transpose(0, 1), _derivative(img)


def _derivative(x: torch.Tensor) -> torch.Tensor:  # [n, ...] -> d/di along the first axis
    g = torch.empty_like(x)
    g[2:-2] = (x[:-4] - 8 * x[1:-3] + 8 * x[3:-1] - x[4:]) / 12
    g[1], g[-2] = 0.5 * (x[2] - x[0]), 0.5 * (x[-1] - x[-3])
    g[0], g[-1] = x[1] - x[0], x[-1] - x[-2]
    return g


def front_depth(depth: torch.Tensor, window: int = FRONT_WINDOW) -> torch.Tensor:  # [H, W] -> [H, W]
    """The nearest positive rendered depth within the ``window`` x ``window`` square around each pixel
    (odd ``window``; 1: the depth itself); 0 where the pixel's own depth is 0 (nothing rendered)."""
    ok = depth > 0
    if window <= 1:
        return torch.where(ok, depth, torch.zeros_like(depth))
    far = torch.where(ok, depth, torch.full_like(depth, float("inf")))
    near = -torch.nn.functional.max_pool2d(-far[None, None], window, stride=1, padding=window // 2)[0, 0]
    return torch.where(ok, near, torch.zeros_like(depth))


def pixel_motion(K: torch.Tensor, depth: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(d u'/d delta [H, W, 2, 6], d X'_z/d delta / z [H, W, 6]) for the surface at rendered ``depth``
    [H, W] (world units; pixels with depth <= 0 get zeros) under the right perturbation (rho, phi)."""
    H, W = depth.shape
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    v, u = torch.meshgrid(
        torch.arange(H, dtype=depth.dtype, device=depth.device),
        torch.arange(W, dtype=depth.dtype, device=depth.device),
        indexing="ij",
    )
    ok = depth > 0
    z = torch.where(ok, depth, torch.ones_like(depth))
    x, y = (u - cx) / fx, (v - cy) / fy  # X / z, Y / z
    iz = torch.where(ok, 1.0 / z, torch.zeros_like(z))
    zero = torch.zeros_like(z)
    # d X' / d delta = [-I | [X]x], X = z (x, y, 1); rows of [X]x: (0, -Z, Y), (Z, 0, -X), (-Y, X, 0)
    # d u / d X = fx (1/Z, 0, -x/Z), d v / d X = fy (0, 1/Z, -y/Z)
    du = torch.stack([-iz, zero, x * iz, x * y, -(1 + x * x), y], dim=-1) * fx  # [H, W, 6]
    dv = torch.stack([zero, -iz, y * iz, 1 + y * y, -x * y, -x], dim=-1) * fy
    dz = torch.stack([zero, zero, -iz, -y, x, zero], dim=-1)  # d Z'/d delta / Z
    dz = dz * ok[..., None]
    return torch.stack([du, dv], dim=-2) * ok[..., None, None], dz


def subpixel_intrinsics(intrinsics: CameraIntrinsics, step: float = SUBPIXEL):
    """The cameras whose renders are the render at ``u + step`` and at ``v + step``: the principal point
    moved by ``-step`` (a render's pixel ``u`` sees what the original camera sees at ``u - dcx``)."""
    return (
        dataclasses.replace(intrinsics, cx=intrinsics.cx - step),
        dataclasses.replace(intrinsics, cy=intrinsics.cy - step),
    )


def _slopes(out, shifted, step: float):  # -> ((d/du, d/dv) of colour, alpha, log depth)
    logz = lambda o: torch.log(o.depth.clamp_min(1e-6))  # noqa: E731
    if shifted is None:  # five-point slopes of the one render
        return image_gradient(out.color), image_gradient(out.alpha), image_gradient(logz(out))
    su, sv = shifted  # the render's own slopes: one-sided differences over ``step`` pixels
    return tuple(
        ((f(su) - f(out)) / step, (f(sv) - f(out)) / step)
        for f in (lambda o: o.color, lambda o: o.alpha, logz)
    )


def warp_jacobians(
    out,
    image: torch.Tensor,
    K: torch.Tensor,
    window: int = FRONT_WINDOW,
    shifted=None,
    step: float = SUBPIXEL,
):
    """Pose Jacobians [H, W, 6] of a render ``out`` (:class:`~gsslam.mapping.rasterize.RenderOutput`):
    of the premultiplied colour residual ``color - image * alpha`` ([H, W, 3, 6]) and of the log depth
    ([H, W, 6]), over the right perturbation (rho, phi); ``image`` [H, W, 3] is the observation. Pixels
    move with the nearest depth within ``window`` (:func:`front_depth`; 1: their own rendered depth).
    ``shifted``: the renders at the same pose from :func:`subpixel_intrinsics` (``step``), whose
    differences to ``out`` are the render's exact slopes; None: five-point slopes of ``out``."""
    motion, _ = pixel_motion(K, front_depth(out.depth, window))  # [H, W, 2, 6]
    _, dz = pixel_motion(K, out.depth)  # [H, W, 6]: the depth's own change, at the pixel's depth
    (cu, cv), (au, av), (zu, zv) = _slopes(out, shifted, step)  # [H, W, 3] / [H, W] each
    cu, cv = cu - image * au[..., None], cv - image * av[..., None]  # only the render moves, not the image
    Jc = -(cu[..., None] * motion[:, :, None, 0] + cv[..., None] * motion[:, :, None, 1])  # [H, W, 3, 6]
    Jd = dz - (zu[..., None] * motion[:, :, 0] + zv[..., None] * motion[:, :, 1])  # [H, W, 6]
    return Jc, Jd
