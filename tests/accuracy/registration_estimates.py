"""Depth-to-colour registration estimates on teddy playbacks, with and without the fallback pairs.

    PYTHONPATH=. python tests/accuracy/registration_estimates.py ROW [ROW ...] [--frames 40] \
        [--fallback none 2]

ROW: ``s2_7s`` (``teddy200_s2_blur_7scenes``), ``s2`` (``teddy200_s2_blur``), ``s3``
(``teddy200_s3_blur_rgbd``), ``s3_7s`` (that playback with the 7-Scenes handout), ``bundled_7s`` /
``bundled`` (the bundled 60 frames played 2x with blur, as ``tests/frontend/test_registration_pairs.py``).
For each row and fallback gap (``none`` or a number) prints the pairs, the depth-given fit (k, baseline)
and the error at k = 1 and at the fit. Not a test: a measuring tool (docs/results.md, "Depth not
registered to colour, session 9").
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from gsslam.config import FlowConfig
from gsslam.datasets.base import open_dataset
from gsslam.frontend.colour_focal import flow_pairs
from gsslam.frontend.depth_registration import fit_registration
from gsslam.frontend.flow import make_flow_estimator

ROOT = Path(__file__).resolve().parents[2]
TEDDY = ROOT.parent / "shared" / "data" / "rgbd_dataset_freiburg3_teddy"
BUNDLED = ROOT / "data" / "rgbd_dataset_freiburg3_teddy_60"
DEG = {"shutter": 0.5, "exposure_amp": 0.25, "exposure_period": 150}
MIS = {"baseline_m": 0.025, "focal_scale": 1.114, "report": "depth"}
ROWS = {
    "s2_7s": (TEDDY, dict(pattern="fbfbf", stride=2, degrade=DEG, misregister=MIS)),
    "s2": (TEDDY, dict(pattern="fbfbf", stride=2, degrade=DEG)),
    "s3": (TEDDY, dict(pattern="fbfbfbf", stride=3, degrade=DEG)),
    "s3_7s": (TEDDY, dict(pattern="fbfbfbf", stride=3, degrade=DEG, misregister=MIS)),
    "bundled_7s": (BUNDLED, dict(pattern="f", stride=2, degrade=DEG, misregister=MIS)),
    "bundled": (BUNDLED, dict(pattern="f", stride=2, degrade=DEG)),
}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("rows", nargs="+", choices=sorted(ROWS))
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--fallback", nargs="+", default=["none", "2"])
    a = ap.parse_args()
    flow = make_flow_estimator(FlowConfig())
    for name in a.rows:
        path, kw = ROWS[name]
        ds = open_dataset("playback", str(path), base="tum", **kw)
        frames = [ds[i] for i in range(min(a.frames, len(ds)))]
        for fb in a.fallback:
            t = time.perf_counter()
            pairs = flow_pairs(frames, flow, fallback_gap=None if fb == "none" else int(fb))
            r = fit_registration(pairs, frames[0].intrinsics, hypotheses=("depth",))
            print(f"{name} fallback {fb}: pairs {r.pairs}, points {r.points}, k {r.ratio:.4f}, "
                  f"b {1000 * r.baseline_m:.1f} mm, error {r.cost_registered:.3f} -> {r.cost:.3f} px, "
                  f"ok {r.ok} ({time.perf_counter() - t:.0f} s)", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
