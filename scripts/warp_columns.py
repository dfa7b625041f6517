"""The warp pose Jacobian against central differences of renders, column by column (session 7, issue #17).

    python3 scripts/warp_columns.py teddy [WINDOW ...]  # bundled teddy: 2-keyframe map, frame 10's pose
    python3 scripts/warp_columns.py planes [WINDOW ...]  # synthetic ``planes``: a panel before a wall
    python3 scripts/warp_columns.py snap SNAP.pt [WINDOW ...]  # saved by registration_cost.py snap

With the five-point slopes of the one render (``warp``) and with the render's exact slopes from two
renders with the principal point moved 0.1 px (``subpixel``), for each pixel-motion window
(``render_jacobian.front_depth``; 1 = the rendered depth itself, the session-6 warp) and each pose
column (rho x y z, phi x y z), on the pixels the registration uses (alpha > 0.9):
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
from gsslam.mapping.state import MapState

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from helpers.warp_columns import columns, planes_frames, two_keyframe_map  # noqa: E402

CFG = MapperConfig(max_side=120, iterations=20, window=4, device="cpu", lambda_depth=0.5, feedback_min_age=0)


def teddy_case():
    from helpers.tum import load_tum

    f0, f1, f2 = load_tum(ROOT / "data" / "rgbd_dataset_freiburg3_teddy_60", [5, 10, 15], gt_pose="nearest")
    return two_keyframe_map(CFG, f0, f1, f2)


def planes_case():
    return two_keyframe_map(CFG, *planes_frames())


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
        path, args = args[0], args[1:]
    windows = [int(a) for a in args] or [1, 5]
    cases = snap_cases(path) if which == "snap" else [{"teddy": teddy_case, "planes": planes_case}[which]()]
    rows = {}
    for st, kf in cases:
        for subpixel in (False, True):
            res = columns(st, kf, windows, subpixel)
            for w in windows:
                name = f"{'subpixel' if subpixel else 'five-point'} slopes, window {w}"
                rows.setdefault(name, []).append(res[w])
                print(f"kf {kf.index} {name}: {_fmt(res[w])}", flush=True)
    for name, r in rows.items():
        if len(r) > 1:
            med = {k: np.median([x[k] for x in r], 0) for k in r[0]}
            print(f"median of {len(r)}, {name}: {_fmt(med)}")


if __name__ == "__main__":
    main(*sys.argv[1:])
