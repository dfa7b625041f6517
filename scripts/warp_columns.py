"""The warp pose Jacobian against central differences of renders, column by column (session 7, issue #17).

    python3 scripts/warp_columns.py teddy [WINDOW ...]      # bundled teddy: 2-keyframe map, frame 10's pose
    python3 scripts/warp_columns.py planes [WINDOW ...]     # synthetic ``planes`` scene (a panel before a wall)
    python3 scripts/warp_columns.py snap SNAP.pt [WINDOW ...]  # registrations saved by registration_cost.py snap

For each pixel-motion window (``render_jacobian.front_depth``; 1 = the rendered depth itself, the session-6
warp) and each pose column (rho x y z, phi x y z), on the pixels the registration uses (alpha > 0.9):
``cos`` the cosine between the warp's and the numerical column, ``gain`` the warp's projection on the
numerical column (<warp, num> / <num, num>: 0.85 = 15 % short); colour residual and log depth apart.
docs/results.md, "Registration Jacobian, session 7".
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

from gsslam.config import MapperConfig
from gsslam.geometry import make_T, so3_exp
from gsslam.mapping.keyframes import make_keyframe
from gsslam.mapping.mapper import GaussianMapper
from gsslam.mapping.render_jacobian import warp_jacobians
from gsslam.mapping.state import MapState, render

ROOT = Path(__file__).resolve().parents[1]
CFG = MapperConfig(max_side=120, iterations=20, window=4, device="cpu", lambda_depth=0.5, feedback_min_age=0)


def _residuals(st: MapState, kf, delta):  # premultiplied colour residual [h, w, 3], log depth [h, w], render
    kf.delta = delta
    out = render(st, kf.T_cam_world(st.device))
    return out.color - kf.image * out.alpha[..., None], torch.log(out.depth.clamp_min(1e-6)), out


@torch.no_grad()
def columns(st: MapState, kf, windows=(1, 5)) -> dict[int, dict[str, np.ndarray]]:
    """{window: {cos_c, gain_c, cos_d, gain_d: [6]}} at ``kf``'s current delta (restored after)."""
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
    res = {}
    for w in windows:
        Jc, Jd = warp_jacobians(out, kf.image, st.K, window=w)
        row = {}
        for name, a, n in (("c", Jc[mask].reshape(-1, 6).double(), num_c), ("d", Jd[mask].double(), num_d)):
            row["cos_" + name] = ((a * n).sum(0) / (a.norm(dim=0) * n.norm(dim=0)).clamp_min(1e-30)).numpy()
            row["gain_" + name] = ((a * n).sum(0) / (n * n).sum(0).clamp_min(1e-30)).numpy()
        res[w] = row
    return res


def teddy_case():
    sys.path.insert(0, str(ROOT / "tests"))
    from helpers.tum import load_tum

    f0, f1, f2 = load_tum(ROOT / "data" / "rgbd_dataset_freiburg3_teddy_60", [5, 10, 15], gt_pose="nearest")
    return _two_keyframe_map(f0, f2, f1)


def planes_case():
    """The ``planes`` scene (a floating panel 2.5 m before a wall at 4 m, floor, side wall), RGB-D, two
    keyframes 20 cm apart, registered at a pose between them (rotated 2 degrees)."""
    sys.path.insert(0, str(ROOT / "tests"))
    from helpers.plane_scene import PlaneScene

    poses = [
        make_T(np.eye(3), np.array([-0.1, 0.0, 0.0])),
        make_T(so3_exp(np.radians([1.0, 2.0, 0.5])), np.array([0.02, 0.03, 0.1])),
        make_T(np.eye(3), np.array([0.1, 0.0, 0.05])),
    ]
    f0, f1, f2 = PlaneScene().frames(poses, with_depth=True)
    return _two_keyframe_map(f0, f2, f1)


def _two_keyframe_map(f0, f2, f1):
    torch.manual_seed(0)
    m = GaussianMapper(CFG, f0.intrinsics)
    m.add_keyframe(f0, f0.T_world_cam_gt, 0)
    m.add_keyframe(f2, f2.T_world_cam_gt, 0)
    m.optimize(30)
    st = m.map
    kf = make_keyframe(CFG, f1, f1.T_world_cam_gt, -1, (st.intrinsics.width, st.intrinsics.height), st.device)
    return st, kf


def snap_cases(path: str):
    for s in torch.load(path, weights_only=False):
        parts = {k: s[k] for k in ("cfg", "intrinsics", "K", "strategy", "model", "backend")}
        yield MapState(device=torch.device("cpu"), densify_state={}, **parts), s["kf"]


def _fmt(row: dict) -> str:
    f = lambda a: " ".join(f"{x:.3f}" for x in a)  # noqa: E731
    return (
        f"colour cos [{f(row['cos_c'])}] gain [{f(row['gain_c'])}] | "
        f"log depth cos [{f(row['cos_d'])}] gain [{f(row['gain_d'])}]"
    )


def main(which: str, *args: str) -> None:
    torch.set_num_threads(1)
    if which == "snap":
        cases, windows = snap_cases(args[0]), [int(a) for a in args[1:]] or [1, 5]
    else:
        cases = [{"teddy": teddy_case, "planes": planes_case}[which]()]
        windows = [int(a) for a in args] or [1, 5]
    rows = {w: [] for w in windows}
    for st, kf in cases:
        res = columns(st, kf, windows)
        for w in windows:
            rows[w].append(res[w])
            print(f"kf {kf.index} window {w}: {_fmt(res[w])}", flush=True)
    if len(rows[windows[0]]) > 1:
        for w in windows:
            med = {k: np.median([r[k] for r in rows[w]], 0) for k in rows[w][0]}
            print(f"median of {len(rows[w])}, window {w}: {_fmt(med)}")


if __name__ == "__main__":
    main(*sys.argv[1:])
