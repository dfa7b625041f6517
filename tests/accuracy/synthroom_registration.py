"""Depth-to-colour registration estimates on the long synthetic room, one degradation at a time.

    PYTHONPATH=. python tests/accuracy/synthroom_registration.py [CASE ...] [--frames 40] [--fallback 2]

CASE: ``misreg`` (exact depth, misregistered), ``misreg_noise`` (+ the Kinect v1 sensor), ``misreg_blur``
(+ blur and exposure), ``all`` (the ``synth_room1000_kinect`` row). Prints the depth-given fit (k, baseline;
true 1.114, 25 mm) as the runner estimates it from the first frames. Not a test: a measuring tool
(docs/results.md, "A long synthetic room, session 12").
"""

from __future__ import annotations

import argparse
import time

from gsslam.config import FlowConfig
from gsslam.datasets.synthetic import SyntheticDataset
from gsslam.frontend.colour_focal import flow_pairs
from gsslam.frontend.depth_registration import fit_registration
from gsslam.frontend.flow import make_flow_estimator

BASE = dict(n_frames=1000, width=320, height=240, scene="furnished_room", trajectory="room_walk", seed=0)
MIS = {"baseline_m": 0.025, "focal_scale": 1.114, "report": "depth"}
DEG = {"shutter": 0.5, "exposure_amp": 0.25, "exposure_period": 150}
CASES = {
    "misreg": dict(misregister=MIS),
    "misreg_noise": dict(misregister=MIS, sensor="kinect_v1"),
    "misreg_blur": dict(misregister=MIS, degrade=DEG),
    "all": dict(misregister=MIS, sensor="kinect_v1", degrade=DEG),
}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("cases", nargs="*", help=f"any of {sorted(CASES)} (default: all four)")
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--fallback", default="2")
    a = ap.parse_args()
    flow = make_flow_estimator(FlowConfig())
    for name in a.cases or list(CASES):
        ds = SyntheticDataset(**BASE, **CASES[name])
        frames = [ds[i] for i in range(a.frames)]
        t = time.perf_counter()
        pairs = flow_pairs(frames, flow, fallback_gap=None if a.fallback == "none" else int(a.fallback))
        r = fit_registration(pairs, frames[0].intrinsics, hypotheses=("depth",))
        print(f"{name}: pairs {r.pairs}, points {r.points}, k {r.ratio:.4f}, b {1000 * r.baseline_m:.1f} mm, "
              f"error {r.cost_registered:.3f} -> {r.cost:.3f} px, ok {r.ok} ({time.perf_counter() - t:.0f} s)",
              flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
