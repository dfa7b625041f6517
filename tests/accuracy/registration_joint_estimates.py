"""The registration estimate as a run makes it (first 40 frames), with the baseline from fixed ICP motions and
from motions re-solved with the flow (``encoder.colour_registration_joint_weight``), on the 7-Scenes-like
rows: the long synthetic room (depth camera ray-cast) and the teddy playbacks. Truth: k 1.114, b 25 mm.
Not a test: a measuring tool (docs/results.md, "Depth re-projected by interpolation, and the registration
baseline, session 14").

    PYTHONPATH=. python3 tests/accuracy/registration_joint_estimates.py [ROW ...] [--weights 0,0.1] [--start 0] \
        [--preset medium] [--max-side 640] [--handeye] [--rotation-deg 0.468,-0.452,-0.155] \
        [--offset 0.0001,0.002] [--baseline 0.025]

``--rotation-deg`` / ``--offset`` / ``--baseline``: the simulated depth camera's rotation, y/z offset and
x baseline (misregister.rotation_deg / offset_m / baseline_m; session 16, "The depth camera's rotation
against the colour camera").
"""

from __future__ import annotations

import argparse
import time

from gsslam.config import FlowConfig
from gsslam.datasets import open_dataset
from gsslam.datasets.synthetic import SyntheticDataset
from gsslam.frontend.depth_registration import registration_correction
from gsslam.frontend.flow import make_flow_estimator

TEDDY = "/work/shared/data/rgbd_dataset_freiburg3_teddy"
SEVEN = {"baseline_m": 0.025, "focal_scale": 1.114, "report": "depth"}
FBF = dict(base="tum", pattern="fbf", pause_every=97, pause_len=15, jump_every=151, jump_len=4, seed=0)
BLUR = {"shutter": 0.5, "exposure_amp": 0.25, "exposure_period": 150}
ROOM = dict(n_frames=1000, width=320, height=240, scene="furnished_room", trajectory="room_walk", seed=0,
            sensor="kinect_v1")  # fmt: skip
ROWS = {  # each takes the misregister dict's extra keys (rotation_deg, offset_m, baseline_m)
    "room_rc": lambda x: SyntheticDataset(**ROOM, misregister={**SEVEN, "raycast": True, **x}, degrade=BLUR),
    "room_splat": lambda x: SyntheticDataset(**ROOM, misregister={**SEVEN, **x}, degrade=BLUR),
    "fbf_7scenes": lambda x: open_dataset("playback", TEDDY, **FBF, misregister={**SEVEN, **x}),
    "s2_blur_7scenes": lambda x: open_dataset(
        "playback", TEDDY, base="tum", pattern="fbfbf", stride=2, degrade=BLUR, misregister={**SEVEN, **x}
    ),
    "fbf_misreg": lambda x: open_dataset(
        "playback", TEDDY, **FBF, misregister={**SEVEN, "report": "colour", **x}
    ),
}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("rows", nargs="*")
    ap.add_argument("--weights", default="0,0.1")
    ap.add_argument("--start", type=int, default=0)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--preset", default="ultrafast", help="flow.dis_preset for the registration's flow")
    ap.add_argument("--max-side", type=int, default=320, help="flow.max_side for the registration's flow")
    ap.add_argument("--handeye", action="store_true", help="encoder.colour_registration_handeye (session 15)")
    ap.add_argument("--rotation-deg", default="0,0,0", help="misregister.rotation_deg: rx,ry,rz")
    ap.add_argument("--offset", default="0,0", help="misregister.offset_m: ty,tz")
    ap.add_argument("--baseline", type=float, default=SEVEN["baseline_m"], help="misregister.baseline_m")
    a = ap.parse_args()
    extra = {
        "rotation_deg": [float(x) for x in a.rotation_deg.split(",")],
        "offset_m": [float(x) for x in a.offset.split(",")],
        "baseline_m": a.baseline,
    }
    flow = make_flow_estimator(FlowConfig(dis_preset=a.preset, max_side=a.max_side))
    for row in a.rows or list(ROWS):
        ds = ROWS[row](extra)
        frames = [ds[i] for i in range(a.start, a.start + a.frames)]
        for w in (float(x) for x in a.weights.split(",")):
            t = time.perf_counter()
            reg, est = registration_correction(frames, flow, 0.02, 0.01, 0.15, 2, joint_weight=w, handeye=a.handeye)
            alone = " ".join(f"{1000 * b:.0f}" for b in est.pair_baselines_m)
            print(f"{row} ({a.preset}, {a.max_side} px) frames {a.start}-{a.start + a.frames - 1} joint_weight {w:g}: {est.pairs} pairs, "
                  f"k {est.ratio:.4f}, b {1000 * est.baseline_m:.1f} mm (fixed motions "
                  f"{1000 * est.baseline_m_fixed_motion:.1f}; hand-eye {1000 * est.baseline_m_handeye:.1f}, "
                  f"median chi2 "
                  f"{est.handeye_median_chi2:.1f}), cost {est.cost:.4f} px, applied {not reg.is_identity()}; "
                  f"alone: {alone} "
                  f"({time.perf_counter() - t:.0f} s)", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
