"""Projection of 3D Gaussians to the image plane (EWA splatting), shared by every rasterizer backend.

Pure torch and differentiable w.r.t. the Gaussian parameters and ``T_cam_world``. Pixel ``(u, v)``
has its centre at integer coordinates (OpenCV convention, the one of :class:`gsslam.types.CameraIntrinsics`).

Gaussian rotations are quaternions in (w, x, y, z) order (unnormalized is fine).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from gsslam.errors import GsslamError

LOW_PASS = 0.3  # px^2 added to the 2D covariance (3DGS anti-aliasing low-pass filter)
SIGMA_CUTOFF = 3.0  # a Gaussian touches a pixel only inside its 3-sigma ellipse
POWER_CUTOFF = 0.5 * SIGMA_CUTOFF**2  # 0.5 * d^T Sigma2d^-1 d above this: no contribution
ALPHA_MIN = 1.0 / 255.0  # smaller per-pair alphas are skipped
ALPHA_MAX = 0.99  # per-pair alpha clamp
T_MIN = 1e-4  # transmittance early stop


class RasterizeError(GsslamError):
    """Inputs to the Gaussian rasterizer have wrong shapes, dtypes or devices, or a backend is missing."""


@dataclass
class Projected:
    """Per-Gaussian image-plane quantities; ``radii == 0`` marks Gaussians that draw nothing."""

    means2d: Tensor  # [N, 2] projected centres (px)
    cov2d: Tensor  # [N, 2, 2] 2D covariance incl. the low-pass term (px^2)
    conics: Tensor  # [N, 3] (a, b, c) of the inverse covariance [[a, b], [b, c]]
    depths: Tensor  # [N] camera z of the centres (m)
    radii: Tensor  # [N] int64 pixel radius, ceil(3 sqrt(largest eigenvalue)); 0 = not visible
    normals: Tensor  # [N, 3] camera-frame shortest-axis normals, flipped to face the camera


def quat_to_rotmat(quats: Tensor) -> Tensor:  # [N, 4] (w, x, y, z) -> [N, 3, 3]
    q = quats / quats.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = q.unbind(-1)
    R = torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    )
    return R.reshape(q.shape[:-1] + (3, 3))


def _row_times(v: Tensor, M: Tensor) -> Tensor:  # v [N, 3], M [N, 3, 3] -> v^T M [N, 3]
    return v[:, 0:1] * M[:, 0] + v[:, 1:2] * M[:, 1] + v[:, 2:3] * M[:, 2]


def check_inputs(means, quats, scales, opacities, colors, T_cam_world, K, width, height) -> None:
    n = means.shape[0] if means.dim() == 2 else -1
    expected = {
        "means": (means, (n, 3)),
        "quats": (quats, (n, 4)),
        "scales": (scales, (n, 3)),
        "opacities": (opacities, (n,)),
        "colors": (colors, (n, 3)),
        "T_cam_world": (T_cam_world, (4, 4)),
        "K": (K, (3, 3)),
    }
    for name, (t, shape) in expected.items():
        if not isinstance(t, Tensor):
            raise RasterizeError(f"{name} must be a torch.Tensor, got {type(t).__name__}")
        if tuple(t.shape) != shape:
            raise RasterizeError(
                f"{name} must have shape {list(shape)} (N = len(means)), got {list(t.shape)}"
            )
        if not t.is_floating_point():
            raise RasterizeError(f"{name} must be a floating-point tensor, got {t.dtype}")
        if t.device != means.device:
            raise RasterizeError(f"{name} is on {t.device} but means is on {means.device}; use one device")
    if int(width) <= 0 or int(height) <= 0:
        raise RasterizeError(f"image size must be positive, got {width}x{height}")


def _tan_limits(fx, fy, cx, cy, width: int, height: int):
    """Clamp of ``x/z`` and ``y/z``, 30 % of the half field of view beyond the image (as in 3DGS/gsplat):
    ``(lim_x_pos, lim_x_neg, lim_y_pos, lim_y_neg)``."""
    tan_x, tan_y = 0.5 * width / fx, 0.5 * height / fy
    return (
        (width - cx) / fx + 0.3 * tan_x,
        cx / fx + 0.3 * tan_x,
        (height - cy) / fy + 0.3 * tan_y,
        cy / fy + 0.3 * tan_y,
    )


def project_gaussians(
    means: Tensor,  # [N, 3] world
    quats: Tensor,  # [N, 4] (w, x, y, z)
    scales: Tensor,  # [N, 3] linear
    T_cam_world: Tensor,  # [4, 4]
    K: Tensor,  # [3, 3]
    width: int,
    height: int,
    near: float = 0.01,
    low_pass: float = LOW_PASS,
) -> Projected:
    """EWA projection: ``Sigma2d = J W Sigma W^T J^T + low_pass I`` with the 3DGS clamp of ``x/z``.

    ``low_pass`` (px^2, default the 3DGS 0.3) is the screen-space dilation; a map fitted at a coarser
    resolution keeps its look when rendered ``z`` times finer with ``low_pass * z^2`` (docs/rasterizer.md).
    """
    dtype = means.dtype
    T = T_cam_world.to(dtype)
    Kd = K.to(dtype)
    R_cw, t_cw = T[:3, :3], T[:3, 3]
    p_cam = means @ R_cw.T + t_cw  # [N, 3]
    x, y, z = p_cam.unbind(-1)
    fx, fy, cx, cy = Kd[0, 0], Kd[1, 1], Kd[0, 2], Kd[1, 2]
    in_front = z > near
    z_safe = torch.where(in_front, z, torch.ones_like(z))
    inv_z = 1.0 / z_safe
    means2d = torch.stack([fx * x * inv_z + cx, fy * y * inv_z + cy], dim=-1)

    # Jacobian of the perspective projection, with x/z and y/z clamped slightly beyond the image
    # (as in 3DGS/gsplat) so that Gaussians far outside the view do not blow up.
    lim_x_pos, lim_x_neg, lim_y_pos, lim_y_neg = _tan_limits(fx, fy, cx, cy, width, height)
    tx = z_safe * torch.minimum(torch.maximum(x * inv_z, -lim_x_neg), lim_x_pos)
    ty = z_safe * torch.minimum(torch.maximum(y * inv_z, -lim_y_neg), lim_y_pos)
    # rows of J W (J = [[fx/z, 0, -fx tx/z^2], [0, fy/z, -fy ty/z^2]], W = R_cw), written out
    # elementwise: batched 3x3 matmuls are slow on CPU for large N
    jw0 = (fx * inv_z)[:, None] * R_cw[0] - (fx * tx * inv_z * inv_z)[:, None] * R_cw[2]  # [N, 3]
    jw1 = (fy * inv_z)[:, None] * R_cw[1] - (fy * ty * inv_z * inv_z)[:, None] * R_cw[2]  # [N, 3]

    R_g = quat_to_rotmat(quats)  # [N, 3, 3] world <- gaussian
    # Sigma2d = (J W R S)(J W R S)^T; rows of A = J W R S:
    A0 = _row_times(jw0, R_g) * scales  # [N, 3]
    A1 = _row_times(jw1, R_g) * scales  # [N, 3]
    a = (A0 * A0).sum(-1) + low_pass
    b = (A0 * A1).sum(-1)
    c = (A1 * A1).sum(-1) + low_pass
    cov2d = torch.stack([a, b, b, c], dim=-1).reshape(-1, 2, 2)
    det = (a * c - b * b).clamp_min(1e-12)
    conics = torch.stack([c / det, -b / det, a / det], dim=-1)

    # shortest axis, rotated into the camera frame, flipped to face the camera
    sd = scales.detach()
    m0 = (sd[:, 0] <= sd[:, 1]) & (sd[:, 0] <= sd[:, 2])
    m1 = ~m0 & (sd[:, 1] <= sd[:, 2])
    onehot = torch.stack([m0, m1, ~(m0 | m1)], dim=-1).to(dtype)  # [N, 3] first smallest axis
    n_world = R_g[:, :, 0] * onehot[:, :1] + R_g[:, :, 1] * onehot[:, 1:2] + R_g[:, :, 2] * onehot[:, 2:]
    n_cam = n_world @ R_cw.T
    facing = torch.where((n_cam * p_cam).sum(-1, keepdim=True).detach() > 0, -1.0, 1.0).to(dtype)
    normals = n_cam * facing

    with torch.no_grad():
        mid = 0.5 * (a + c)
        lam_max = mid + torch.sqrt((mid * mid - (a * c - b * b)).clamp_min(0.0))
        radii = torch.ceil(SIGMA_CUTOFF * torch.sqrt(lam_max)).to(torch.int64)
        u, v = means2d[:, 0], means2d[:, 1]
        on_screen = (u + radii >= 0) & (u - radii <= width - 1) & (v + radii >= 0) & (v - radii <= height - 1)
        visible = in_front & on_screen & torch.isfinite(u) & torch.isfinite(v)
        radii = torch.where(visible, radii, torch.zeros_like(radii))
    return Projected(means2d=means2d, cov2d=cov2d, conics=conics, depths=z, radii=radii, normals=normals)


@torch.no_grad()
def in_view(
    means: Tensor,  # [N, 3] world
    scales: Tensor,  # [N, 3] linear
    T_cam_world: Tensor,  # [4, 4]
    K: Tensor,  # [3, 3]
    width: int,
    height: int,
    near: float = 0.01,
    low_pass: float = LOW_PASS,
) -> tuple[Tensor, Tensor, Tensor]:
    """Conservative frustum test: ``(keep [N] bool, centres [N, 2] px, z [N])``, no gradients.

    ``keep`` is False only for Gaussians that :func:`project_gaussians` would give ``radii == 0``
    (behind ``near``, or off the image by more than their radius), so rendering only the kept ones
    draws the same image. The radius is bounded without the rotation: the 2D covariance's trace is at
    most ``(f s_max / z)^2 (1 + lim^2) + low_pass`` per axis (``lim`` the clamp of ``x/z``), and the largest
    eigenvalue at most the trace. ``centres`` and ``z`` are the projection of every centre (the values
    :func:`project_gaussians` returns for them).
    """
    dtype = means.dtype
    T = T_cam_world.detach().to(dtype)
    Kd = K.detach().to(dtype)
    p = means.detach() @ T[:3, :3].T + T[:3, 3]  # [N, 3]
    x, y, z = p.unbind(-1)
    fx, fy, cx, cy = Kd[0, 0], Kd[1, 1], Kd[0, 2], Kd[1, 2]
    front = z > near
    inv_z = 1.0 / torch.where(front, z, torch.ones_like(z))
    u, v = fx * x * inv_z + cx, fy * y * inv_z + cy
    lim_x_pos, lim_x_neg, lim_y_pos, lim_y_neg = _tan_limits(fx, fy, cx, cy, width, height)
    lim_x, lim_y = torch.maximum(lim_x_pos, lim_x_neg), torch.maximum(lim_y_pos, lim_y_neg)
    s = scales.detach().amax(dim=-1) * inv_z  # [N]
    trace = s * s * (fx * fx * (1 + lim_x * lim_x) + fy * fy * (1 + lim_y * lim_y)) + 2 * low_pass
    r = SIGMA_CUTOFF * torch.sqrt(trace) * 1.001 + 1.0  # px, >= the radius project_gaussians finds
    keep = front & (u + r >= 0) & (u - r <= width - 1) & (v + r >= 0) & (v - r <= height - 1)
    return keep, torch.stack([u, v], dim=-1), z
