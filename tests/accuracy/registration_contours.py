"""The depth-to-colour baseline from single frames' occluding contours: a measuring tool, NOT used by runs.

    PYTHONPATH=. python tests/accuracy/registration_contours.py ROW START COUNT [K [GIVEN]]

ROW: ``room_all`` (the ``synth_room1000_kinect`` frames), ``room_exact`` (misregistered exact depth),
``fbf_7s``, ``fbf_misreg``, ``s2_7s`` (teddy playbacks). Measured (docs/results.md, "The registration
baseline under Kinect noise, session 13"; true 25 mm): room exact 0-39 25.0 mm, room Kinect 200-239
24.4 mm (its frames 0-79 have no contours), but teddy fbf_7scenes 34.0 and s2_blur_7scenes 47.5 mm:
real Kinect depth edges do not sit where the colour edges are, so the flow fit (25.9 / 25.5) stays.

The depth-to-colour baseline from single frames: where the colour image sees the depth's occluding contours.

The flow fit of :mod:`gsslam.frontend.depth_registration` observes the baseline ``b`` weakly: for a turn
of ``theta`` the two camera centres differ by ``theta b`` (~1 mm for 2 deg and 25 mm), so an ICP
translation error of 0.3 mm moves ``b`` by ~10 mm, and a flow field smoothed across occlusion boundaries
by ~0.05 px moves it by 4-9 mm even with the true motion (docs/results.md, "The registration baseline
under Kinect noise, session 13"). A single frame observes it directly: a depth pixel ``(u_d, v, z)`` on
an occluding contour (its neighbour along x, within ``reach`` px, is farther by ``jump`` relative) lands
in the colour image at ``u_c = c + f_c ((u_d - c) / f_d + b / z)``, where the colour image has an edge
(the object against its background). :func:`contour_baseline` scans ``b`` for the largest mean colour
x-gradient at the mapped contour pixels, for contours facing right and left separately: a sensor that
erodes the foreground at its edges (Kinect v1's holes on both sides of a depth edge) or a splat that
dilates it moves the two sides' optimum in opposite directions, so their mean is the estimate.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from gsslam.datasets.base import open_dataset
from gsslam.datasets.synthetic import SyntheticDataset
from gsslam.frontend.depth_registration import DepthRegistration
from gsslam.types import CameraIntrinsics, Frame

SCAN_M = (-0.08, 0.08, 0.002)  # scanned baselines: from, to, step (metres)


@dataclass(frozen=True)
class ContourBaseline:
    baseline_m: float  # the mean of the two sides' optima (nan without evidence)
    right_m: float  # contours whose background is to the right
    left_m: float
    pixels: tuple[int, int]  # contour pixels (right, left) over all frames
    contrast: tuple[float, float]  # each side's peak score / median score over the scan
    ok: bool  # both sides with >= min_pixels, a peak inside the scan, contrast >= min_contrast


def contour_pixels(
    depth: np.ndarray,  # [H, W] metres, NaN / 0 invalid
    side: int,  # +1: the farther surface to the right of the pixel, -1: to the left
    jump: float = 0.08,  # relative depth step (of max(z, 1 m)) that makes an occluding contour
    reach: int = 6,  # px: how far the farther surface may be (a sensor leaves holes at depth edges)
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # u [M], v [M], z [M] of the nearer side's edge pixels
    d = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan).astype(np.float64)
    edge = np.zeros(d.shape, bool)
    for s in range(1, reach + 1):
        nb = np.full_like(d, np.nan)
        if side > 0:
            nb[:, :-s] = d[:, s:]
        else:
            nb[:, s:] = d[:, :-s]
        with np.errstate(invalid="ignore"):
            edge |= nb > d + jump * np.maximum(d, 1.0)
    # only the pixel at the contour: the next one towards the background is not also nearer
    vs, us = np.nonzero(edge)
    step = np.clip(us + side, 0, d.shape[1] - 1)
    last = ~edge[vs, step] | (step == us)
    vs, us = vs[last], us[last]
    return us.astype(np.float64), vs.astype(np.float64), d[vs, us]


def _x_gradient(image: np.ndarray) -> np.ndarray:  # [H, W, 3] in [0, 1] -> [H, W] float32
    g = cv2.GaussianBlur(np.asarray(image, np.float32).mean(axis=2), (0, 0), 1.0)
    return np.abs(cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3))


def _peak(bs: np.ndarray, s: np.ndarray) -> tuple[float, bool, float]:  # (b, inside, contrast)
    j = int(np.argmax(s))
    inside = 0 < j < len(bs) - 1
    b = float(bs[j])
    if inside:
        den = s[j - 1] - 2 * s[j] + s[j + 1]
        if den < 0:
            b += 0.5 * (s[j - 1] - s[j + 1]) / den * float(bs[1] - bs[0])
    med = float(np.median(s))
    return b, inside, float(s[j] / med) if med > 0 else 0.0


def contour_baseline(
    frames: list[Frame],  # with depth (depth camera grid) and colour
    depth_intr: CameraIntrinsics,  # of the depth image
    colour_intr: CameraIntrinsics,  # of the colour image
    min_pixels: int = 300,  # per side
    min_contrast: float = 1.25,
) -> ContourBaseline:
    """The baseline that puts the depth's occluding contours on the colour image's edges (module doc)."""
    bs = np.arange(SCAN_M[0], SCAN_M[1] + 1e-9, SCAN_M[2])
    scores = {1: np.zeros(len(bs)), -1: np.zeros(len(bs))}
    counts = {1: 0, -1: 0}
    for f in frames:
        if f.depth is None:
            continue
        gx = None
        for side in (1, -1):
            u, v, z = contour_pixels(f.depth, side)
            if len(u) == 0:
                continue
            gx = _x_gradient(f.image) if gx is None else gx
            xn = (u - depth_intr.cx) / depth_intr.fx  # [M] normalised depth-camera ray
            vc = (colour_intr.cy + colour_intr.fy * (v - depth_intr.cy) / depth_intr.fy).astype(np.float32)
            for j, b in enumerate(bs):
                uc = (colour_intr.cx + colour_intr.fx * (xn + b / z)).astype(np.float32)
                val = cv2.remap(gx, uc[None], vc[None], cv2.INTER_LINEAR, borderValue=0)
                scores[side][j] += float(val.sum())
            counts[side] += len(u)
    fits = {s: _peak(bs, scores[s] / max(counts[s], 1)) for s in (1, -1)}
    ok = all(counts[s] >= min_pixels and fits[s][1] and fits[s][2] >= min_contrast for s in (1, -1))
    b = 0.5 * (fits[1][0] + fits[-1][0])
    return ContourBaseline(
        b if ok else float("nan"), fits[1][0], fits[-1][0], (counts[1], counts[-1]),
        (fits[1][2], fits[-1][2]), ok,
    )  # fmt: skip


TEDDY = Path(__file__).resolve().parents[3] / "shared" / "data" / "rgbd_dataset_freiburg3_teddy"
DEG = {"shutter": 0.5, "exposure_amp": 0.25, "exposure_period": 150}
MIS = {"baseline_m": 0.025, "focal_scale": 1.114, "report": "depth"}
ROOM = dict(n_frames=1000, width=320, height=240, scene="furnished_room", trajectory="room_walk", seed=0)


def _dataset(name: str):
    if name == "room_all":
        return SyntheticDataset(**ROOM, sensor="kinect_v1", misregister=MIS, degrade=DEG)
    if name == "room_exact":
        return SyntheticDataset(**ROOM, misregister=MIS)
    pb = dict(pattern="fbf", pause_every=97, pause_len=15, jump_every=151, jump_len=4, seed=0)
    kw = {
        "fbf_7s": dict(pb, misregister=MIS),
        "fbf_misreg": dict(pb, misregister=dict(MIS, report="colour")),
        "s2_7s": dict(pattern="fbfbf", stride=2, degrade=DEG, misregister=MIS),
    }[name]
    return open_dataset("playback", str(TEDDY), base="tum", **kw)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("row")
    ap.add_argument("start", type=int)
    ap.add_argument("count", type=int)
    ap.add_argument("k", type=float, nargs="?", default=1.114)
    ap.add_argument("given", nargs="?", default="depth")
    a = ap.parse_args()
    ds = _dataset(a.row)
    frames = [ds[i] for i in range(a.start, a.start + a.count)]
    reg = DepthRegistration(a.k, 0.0, a.given)
    r = contour_baseline(frames, reg.depth_intrinsics(ds.intrinsics), reg.colour_intrinsics(ds.intrinsics))
    print(
        f"{a.row} {a.start}-{a.start + a.count - 1}: b {1000 * r.baseline_m:.1f} mm "
        f"(right {1000 * r.right_m:.1f}, left {1000 * r.left_m:.1f}), pixels {r.pixels}, "
        f"contrast {r.contrast[0]:.2f} / {r.contrast[1]:.2f}, ok {r.ok}"
    )


if __name__ == "__main__":
    main()
