"""Write a dataset (e.g. a 7-Scenes-like playback of teddy) in 7-Scenes' own layout, so that the run the hidden
room gets (``--dataset 7scenes``: the loader's nominal depth-camera intrinsics, 8-bit colour PNGs, depth in mm
with 65535 invalid, ``pose.txt`` of the camera the dataset's ground truth poses) can be replayed end to end.

    PYTHONPATH=. python3 tests/accuracy/write_7scenes_folder.py OUT/seq-01 --frames 300
    gsslam run OUT/seq-01 --dataset 7scenes --mode rgbd --set mapper.enabled=false --out RUN

The default source is the tracking suite's ``teddy200_s2_blur_7scenes`` row (depth camera's ground truth).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from gsslam.datasets.base import open_dataset

S2_BLUR_7SCENES = {
    "base": "tum", "pattern": "fbfbf", "stride": 2,
    "degrade": {"shutter": 0.5, "exposure_amp": 0.25, "exposure_period": 150},
    "misregister": {"baseline_m": 0.025, "focal_scale": 1.114, "report": "depth", "ground_truth": "depth"},
}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("out", type=Path)
    ap.add_argument("--source", default="../shared/data/rgbd_dataset_freiburg3_teddy")
    ap.add_argument("--frames", type=int, default=300)
    a = ap.parse_args()
    ds = open_dataset("playback", a.source, **S2_BLUR_7SCENES)
    K = ds.intrinsics
    if (K.fx, K.fy, K.cx, K.cy, K.width, K.height) != (585.0, 585.0, 320.0, 240.0, 640, 480):
        print(f"note: the source hands out {K}; the 7-Scenes loader will say fx = fy = 585, (320, 240)")
    a.out.mkdir(parents=True, exist_ok=True)
    gt = ds.ground_truth()
    poses = dict(zip(np.round(gt.timestamps, 6), gt.poses))
    n = min(a.frames, len(ds))
    for i in range(n):
        f = ds[i]
        colour = np.clip(np.round(f.image * 255.0), 0, 255).astype(np.uint8)[:, :, ::-1]
        depth = np.where(np.isfinite(f.depth), np.round(f.depth * 1000.0), 65535).astype(np.uint16)
        cv2.imwrite(str(a.out / f"frame-{i:06d}.color.png"), colour)
        cv2.imwrite(str(a.out / f"frame-{i:06d}.depth.png"), depth)
        T = poses.get(round(float(f.timestamp), 6))
        T = np.full((4, 4), np.inf) if T is None else T  # 7-Scenes' convention for an untracked frame
        np.savetxt(a.out / f"frame-{i:06d}.pose.txt", T, fmt="%.9e")
    print(f"{n} frames in {a.out}")


if __name__ == "__main__":
    main()
