"""The warp pose Jacobian (gsslam.mapping.render_jacobian) against central differences of renders."""

from __future__ import annotations

import numpy as np
import torch

from gsslam.config import MapperConfig
from gsslam.geometry import make_T, so3_exp
from gsslam.mapping.keyframes import make_keyframe
from gsslam.mapping.mapper import GaussianMapper
from gsslam.mapping.render_jacobian import subpixel_intrinsics, warp_jacobians
from gsslam.mapping.state import MapState, render
from gsslam.types import Frame


def _residuals(st: MapState, kf, delta):  # premultiplied colour residual [h, w, 3], log depth [h, w], render
    kf.delta = delta
    out = render(st, kf.T_cam_world(st.device))
    return out.color - kf.image * out.alpha[..., None], torch.log(out.depth.clamp_min(1e-6)), out


@torch.no_grad()
def columns(st: MapState, kf, windows=(1, 5), subpixel: bool = False) -> dict[int, dict[str, np.ndarray]]:
    """{window: {cos_c, gain_c, cos_d, gain_d: [6]}} at ``kf``'s current delta (restored after);
    ``subpixel``: the warp with the render's exact slopes (``registration_jacobian=subpixel``)."""
    delta0 = kf.delta.detach().clone()
    _, _, out = _residuals(st, kf, delta0)
    mask = (out.alpha > 0.9) & (out.depth > 1e-3)
    num_c, num_d = [], []
    for i, h in enumerate([1e-3 * kf.median_depth] * 3 + [1e-3] * 3):
        e = torch.zeros(6, dtype=delta0.dtype)
        e[i] = h
        cp, dp, _ = _residuals(st, kf, delta0 + e)
        cm, dm, _ = _residuals(st, kf, delta0 - e)
        num_c.append(((cp - cm) / (2 * h))[mask].reshape(-1))
        num_d.append(((dp - dm) / (2 * h))[mask])
    kf.delta = delta0
    num_c, num_d = torch.stack(num_c, 1).double(), torch.stack(num_d, 1).double()  # [3M, 6], [M, 6]
    shifted = None
    if subpixel:
        T = kf.T_cam_world(st.device)
        shifted = [render(st, T, intrinsics=c) for c in subpixel_intrinsics(st.intrinsics)]
    res = {}
    for w in windows:
        Jc, Jd = warp_jacobians(out, kf.image, st.K, window=w, shifted=shifted)
        row = {}
        for name, a, n in (("c", Jc[mask].reshape(-1, 6).double(), num_c), ("d", Jd[mask].double(), num_d)):
            row["cos_" + name] = ((a * n).sum(0) / (a.norm(dim=0) * n.norm(dim=0)).clamp_min(1e-30)).numpy()
            row["gain_" + name] = ((a * n).sum(0) / (n * n).sum(0).clamp_min(1e-30)).numpy()
        res[w] = row
    return res


def planes_frames() -> list[Frame]:
    """The ``planes`` scene (a floating panel 2.5 m before a wall at 4 m, floor, side wall) with exact
    depth: keyframes 20 cm apart (f0, f2) and a frame between them rotated ~2 degrees (f1)."""
    from helpers.plane_scene import PlaneScene

    poses = [
        make_T(np.eye(3), np.array([-0.1, 0.0, 0.0])),
        make_T(so3_exp(np.radians([1.0, 2.0, 0.5])), np.array([0.02, 0.03, 0.1])),
        make_T(np.eye(3), np.array([0.1, 0.0, 0.05])),
    ]
    return PlaneScene().frames(poses, with_depth=True)


def two_keyframe_map(cfg: MapperConfig, f0: Frame, f1: Frame, f2: Frame):
    """A map of keyframes f0 and f2 at their true poses (30 steps) and f1 as a keyframe at its true pose,
    not part of the map: (MapState, Keyframe)."""
    torch.manual_seed(0)
    m = GaussianMapper(cfg, f0.intrinsics)
    m.add_keyframe(f0, f0.T_world_cam_gt, 0)
    m.add_keyframe(f2, f2.T_world_cam_gt, 0)
    m.optimize(30)
    st = m.map
    size = (st.intrinsics.width, st.intrinsics.height)
    return st, make_keyframe(cfg, f1, f1.T_world_cam_gt, -1, size, st.device)
