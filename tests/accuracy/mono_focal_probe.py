"""Probe of the mono focal self-calibration (gsslam/frontend/mono_focal.py) on the hidden room's proxies.

    PYTHONPATH=.:tests python tests/accuracy/mono_focal_probe.py ROW [--frames 60] [--set gap=3 ...]

ROW: ``s2_blur_7scenes`` (teddy s2_blur handed out at the depth focal, true scale 1/1.114), ``s2_blur``
(right focal, true 1), ``s3_blur`` (the 3x playback, right focal), ``teddy`` (TUM teddy 200, true 1),
``synth_loop`` (the synthetic orbit loop at focal_scale 1.114), ``synth_loop_true`` (the orbit at its true
focal), ``kitti01``, ``kitti06``, ``euroc`` (true 1), ``synth_room`` (the synthetic room scanned by a
hand-held pan, tests/helpers/room_scan.py, focal_scale 1.114; ``synth_room_true`` at the true focal),
``synth_room1000`` / ``synth_room1000_kinect`` (the long synthetic room's walk at focal x1.114, exact / the
tracking suite's kinect row). Data root: $GSSLAM_DATA (default ../shared/data).
Prints the estimate, each window's minimum and the summed profile (docs/results.md, "Mono focal length,
sessions 10 and 13").
"""
import argparse
import os
import time

import numpy as np

from gsslam.config import FlowConfig
from gsslam.datasets import open_dataset
from gsslam.datasets.synthetic.dataset import SyntheticDataset
from helpers.room_scan import room_scan
from gsslam.frontend.flow import make_flow_estimator
from gsslam.frontend.mono_focal import estimate_mono_focal
from gsslam.types import Frame

ROOT = os.environ.get("GSSLAM_DATA", "../shared/data")
DATA = f"{ROOT}/rgbd_dataset_freiburg3_teddy"
S2 = dict(base="tum", pattern="fbfbf", stride=2, degrade=dict(shutter=0.5, exposure_amp=0.25, exposure_period=150))
MIS = dict(baseline_m=0.025, focal_scale=1.114, report="depth")


def frames_of(row: str, n: int) -> tuple[list[Frame], float]:  # -> (frames, true scale)
    if row in ("s2_blur_7scenes", "s2_blur"):
        kw = dict(S2, misregister=MIS) if row == "s2_blur_7scenes" else S2
        ds = open_dataset("playback", DATA, with_depth=False, **kw) if False else open_dataset("playback", DATA, **kw)
        return [ds[i] for i in range(n)], (1 / 1.114 if row == "s2_blur_7scenes" else 1.0)
    if row == "s3_blur":  # the tracking suite's teddy200_s3_blur mono row (right focal)
        ds = open_dataset("playback", DATA, **dict(S2, pattern="fbfbfbf", stride=3))
        return [ds[i] for i in range(n)], 1.0
    if row == "teddy":
        ds = open_dataset("tum", DATA, with_depth=False)
        return [ds[i] for i in range(n)], 1.0
    if row in ("kitti01", "kitti06"):
        ds = open_dataset("kitti", f"{ROOT}/kitti_odometry", sequence=row[-2:])
        return [ds[i] for i in range(min(n, len(ds)))], 1.0
    if row == "euroc":
        ds = open_dataset("euroc", f"{ROOT}/euroc_V1_01_easy")
        return [ds[i] for i in range(min(n, len(ds)))], 1.0
    if row in ("synth_loop", "synth_loop_true"):
        fs = 1.114 if row == "synth_loop" else 1.0
        ds = SyntheticDataset(n_frames=800, width=320, height=240, trajectory="loop", seed=5, focal_scale=fs)
        return [ds[i] for i in range(n)], 1 / fs
    if row in ("synth_room1000", "synth_room1000_kinect"):  # the long synthetic room at focal x1.114
        kw = dict(n_frames=1000, width=320, height=240, scene="furnished_room", trajectory="room_walk", seed=0)
        if row == "synth_room1000":
            kw["focal_scale"] = 1.114
        else:
            kw.update(sensor="kinect_v1", misregister=MIS, degrade=S2["degrade"])
        ds = SyntheticDataset(**kw)
        return [ds[i] for i in range(n)], 1 / 1.114
    if row in ("synth_room", "synth_room_true"):
        fs = 1.114 if row == "synth_room" else 1.0
        ds = SyntheticDataset(n_frames=1, width=320, height=240, seed=5, focal_scale=fs)
        poses = room_scan(n)
        out = []
        for i in range(n):
            img, _ = ds.render(poses[i])
            out.append(Frame(index=i, timestamp=i / 30, image=img, intrinsics=ds.intrinsics))
        return out, 1 / fs
    raise SystemExit(f"unknown row {row}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("row")
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--set", nargs="*", default=[])
    a = ap.parse_args()
    kw = {k: (float(v) if "." in v else int(v)) for k, v in (s.split("=") for s in a.set)}
    frames, true = frames_of(a.row, a.frames)
    t = time.perf_counter()
    est = estimate_mono_focal(frames, make_flow_estimator(FlowConfig()), **kw)
    print(f"{a.row}: true {true:.4f} estimated {est.scale:.4f} ok {est.ok} windows {est.windows} agree {est.agreeing} "
          f"gain {est.gain:.3f} cost {est.cost_given:.0f} -> {est.cost_best:.0f} ({time.perf_counter() - t:.0f} s)")
    print("per window:", " ".join(f"{s:.3f}" for s in est.window_scales))


if __name__ == "__main__":
    main()
