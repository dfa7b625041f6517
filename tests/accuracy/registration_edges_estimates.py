"""The depth camera's turn from edges (gsslam/frontend/registration_edges.py) on the 7-Scenes-like
windows, with the registration's k / b given at the truth (--k, --b) or estimated as a run does
(--estimate). Not a test: a measuring tool (docs/results.md, "The depth camera's turn from edges,
session 17").
"""

from __future__ import annotations

import argparse
import time

from registration_joint_estimates import ROWS, SEVEN

from gsslam.config import FlowConfig
from gsslam.frontend.depth_registration import registration_correction
from gsslam.frontend.flow import make_flow_estimator
from gsslam.frontend.registration_edges import estimate_turn


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("rows", nargs="*")
    ap.add_argument("--start", type=int, default=0)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument(
        "--max-frames", type=int, default=10, help="frames the estimate uses, spread over the window"
    )
    ap.add_argument("--rotation-deg", default="0,0,0")
    ap.add_argument("--offset", default="0,0")
    ap.add_argument("--baseline", type=float, default=SEVEN["baseline_m"])
    ap.add_argument("--k", type=float, default=1.114, help="the registration's k (given)")
    ap.add_argument(
        "--b", type=float, default=None, help="the registration's baseline (given; default --baseline)"
    )
    ap.add_argument(
        "--estimate", action="store_true", help="k / b estimated as a run does (DIS medium, hand-eye)"
    )
    ap.add_argument("--blur", type=float, default=1.0)
    ap.add_argument("--no-shift", action="store_true", help="hold the contours at the gap middle")
    a = ap.parse_args()
    extra = {"rotation_deg": [float(x) for x in a.rotation_deg.split(",")],
             "offset_m": [float(x) for x in a.offset.split(",")], "baseline_m": a.baseline}  # fmt: skip
    for row in a.rows or list(ROWS):
        ds = ROWS[row](extra)
        frames = [ds[i] for i in range(a.start, a.start + a.frames)]
        intr = frames[0].intrinsics
        k, b = a.k, a.baseline if a.b is None else a.b
        if a.estimate:
            flow = make_flow_estimator(FlowConfig(dis_preset="medium", max_side=320))
            _, est = registration_correction(frames, flow, 0.02, 0.01, 0.15, 2, handeye=True)
            k, b = est.ratio, est.baseline_m
        t = time.perf_counter()
        turn = estimate_turn(
            frames,
            intr,
            intr.with_focal(1.0 / k),
            b,
            max_frames=a.max_frames,
            blur_sigma=a.blur,
            fit_shift=not a.no_shift,
        )
        print(f"{row} frames {a.start}-{a.start + a.frames - 1} truth {a.rotation_deg} "
              f"b {1000 * a.baseline:.1f}; "
              f"k {k:.4f} b {1000 * b:.1f} mm: turn ({turn.rotation_deg[0]:.3f}, {turn.rotation_deg[1]:.3f}, "
              f"{turn.rotation_deg[2]:.3f}) deg, observed {turn.observed}, {turn.frames} frames, "
              f"{turn.points_u}+{turn.points_v} pts, score {turn.score_unturned:.4f} -> {turn.score:.4f}, "
              f"shift {turn.shift_px:.2f} px, edges' b {1000 * turn.baseline_m:.1f} mm; "
              f"per frame {turn.frame_rotations_deg} "
              f"({time.perf_counter() - t:.0f} s)", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
