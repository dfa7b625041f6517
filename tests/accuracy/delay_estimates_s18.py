"""The colour-depth delay estimated from a run's registration window (frontend/registration_delay.py), alone,
with the rotations per band of image rows (session 18) or over the whole image (``--bands 1``: session 17's).
Not a test: a measuring tool (docs/results.md, "The delay estimate on real data, session 18"; session 17's
tool tests/accuracy/delay_estimates_s17.py is this with one band).

    PYTHONPATH=. python3 tests/accuracy/delay_estimates_s18.py ROW [ROW ...] [--delays-ms -16,-8,0,8,16] \
        [--starts 0,200] [--frames 120] [--prefixes 40,80] [--registration 1.114,0.025] [--bands 3]

Each stretch: the registration as a run estimates it (its first 40 frames), then the delay from the rotation
rates of pairs (k, k + 2) over the stretch, fitted on the first 40 / 80 / all frames' pairs.

Rows: ``room_splat`` (the suite's synth_room1000_kinect as tests/accuracy/tsync_room400_s16.yaml has it,
with ``depth_delay_s``), ``room_rc`` (the same, depth ray-cast), ``fbf_7scenes`` / ``s2_blur_7scenes`` (the
real TUM teddy 7-Scenes-like playbacks; ``fbf_misreg`` the same with the colour intrinsics given; no delay
can be set: ``--delays-ms`` ignored), ``tum`` (the real
registered teddy: k 1, b 0).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from gsslam.config import FlowConfig
from gsslam.datasets import open_dataset
from gsslam.datasets.synthetic import SyntheticDataset
from gsslam.frontend.colour_focal import flow_pairs
from gsslam.frontend.depth_registration import DepthRegistration, registration_correction
from gsslam.frontend.flow import make_flow_estimator
from gsslam.frontend.registration_delay import BANDS, GAP, fit_delay, frame_interval, rotation_series

TEDDY = "/work/shared/data/rgbd_dataset_freiburg3_teddy"
SEVEN = {"baseline_m": 0.025, "focal_scale": 1.114, "report": "depth"}
FBF = dict(base="tum", pattern="fbf", pause_every=97, pause_len=15, jump_every=151, jump_len=4, seed=0)
BLUR = {"shutter": 0.5, "exposure_amp": 0.25, "exposure_period": 150}
ROOM = dict(n_frames=1000, width=320, height=240, scene="furnished_room", trajectory="room_walk", seed=0,
            sensor="kinect_v1", degrade=BLUR)  # fmt: skip
ROWS = {
    "room_splat": lambda d: SyntheticDataset(
        **ROOM, misregister={**SEVEN, "ground_truth": "depth"}, depth_delay_s=d
    ),
    "room_rc": lambda d: SyntheticDataset(
        **ROOM, misregister={**SEVEN, "ground_truth": "depth", "raycast": True}, depth_delay_s=d
    ),
    "fbf_7scenes": lambda d: open_dataset("playback", TEDDY, **FBF, misregister=SEVEN),
    "s2_blur_7scenes": lambda d: open_dataset(
        "playback", TEDDY, base="tum", pattern="fbfbf", stride=2, degrade=BLUR, misregister=SEVEN
    ),
    "tum": lambda d: open_dataset("tum", TEDDY),
    "fbf_misreg": lambda d: open_dataset(  # colour intrinsics given (the tracking suite's row)
        "playback", TEDDY, **FBF, misregister={"baseline_m": 0.025, "focal_scale": 1.114}
    ),
}
SYNTHETIC = ("room_splat", "room_rc")


def _fit(k, C, D, sd, dt, upto: int) -> str:
    keep = k + GAP < upto
    e = fit_delay(k[keep], C[keep], D[keep], sd[keep], dt)
    return (
        f"tau {1000 * e.delay_s:.2f} ms (sd {1000 * e.std_s:.2f}, {e.pairs} pairs) ok {e.ok} {e.reason!r} "
        f"scales {' '.join(f'{x:.3f}' for x in e.scales)} rms {e.rms_deg_at_zero:.4f} -> {e.rms_deg:.4f} deg "
        f"bands {' '.join(f'{1000 * x:.1f}' for x in e.band_delays_s)} ms"
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("rows", nargs="*")
    ap.add_argument("--delays-ms", default="-16,-8,-4,0,4,8,16")
    ap.add_argument("--starts", default="0,200")
    ap.add_argument("--frames", type=int, default=120, help="the stretch the delay is estimated over")
    ap.add_argument("--prefixes", default="40,80", help="also fitted on the pairs of the first N frames")
    ap.add_argument("--registration", default="", help="k,b_m given (the truth: 1.114,0.025)")
    ap.add_argument("--bands", type=int, default=BANDS, help="bands of image rows (1: the whole image)")
    a = ap.parse_args()
    flow = make_flow_estimator(FlowConfig(dis_preset="medium", max_side=320))
    for row in a.rows or list(ROWS):
        delays = [float(x) for x in a.delays_ms.split(",")] if row in SYNTHETIC else [float("nan")]
        for d_ms in delays:
            ds = ROWS[row](0.0 if np.isnan(d_ms) else d_ms / 1000)
            for start in (int(s) for s in a.starts.split(",")):
                t = time.perf_counter()
                frames = [ds[i] for i in range(start, min(start + a.frames, len(ds)))]
                intr = frames[0].intrinsics
                if row == "tum":  # registered: k 1, b 0
                    reg, col, dep, b = "registered (k 1, b 0)", intr, intr, 0.0
                elif a.registration:  # given
                    k_, b = (float(x) for x in a.registration.split(","))
                    given = DepthRegistration(k_, b, "depth")
                    reg = f"given k {k_:.4f} b {1000 * b:.1f} mm"
                    col, dep = given.colour_intrinsics(intr), given.depth_intrinsics(intr)
                else:  # the registration as a run estimates it (first 40 frames of the stretch)
                    _, est = registration_correction(frames[:40], flow, 0.02, 0.01, 0.15, 2, handeye=True)
                    reg = f"k {est.ratio:.4f} b {1000 * est.baseline_m:.1f} mm"
                    col, dep, b = est.colour_intrinsics(intr), est.depth_intrinsics(intr), est.baseline_m
                pairs = flow_pairs(
                    frames, flow, gap=GAP, max_pairs=len(frames), min_rotation_deg=0.0, icp_refused_ok=True
                )
                k, C, D, sd = rotation_series(pairs, col, dep, b, bands=a.bands)
                dt = frame_interval(frames)
                head = f"{row} bands {a.bands} truth {d_ms:g} ms frames {start}+{len(frames)} ({reg}; "
                head += f"dt {1000 * dt:.1f} ms)"
                for n in [int(x) for x in a.prefixes.split(",") if x] + [len(frames)]:
                    print(f"{head} first {n}: {_fit(k, C, D, sd, dt, n)}", flush=True)
                print(f"  ({time.perf_counter() - t:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
