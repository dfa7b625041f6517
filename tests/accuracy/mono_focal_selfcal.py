"""Focal self-calibration from two-view geometry on the bundled teddy frames (mono; no depth).

    PYTHONPATH=.:tests python tests/accuracy/mono_focal_selfcal.py

For pairs 6 and 10 frames apart: the fundamental matrix from colour flow (RANSAC), then the focal
length whose ``K^T F K`` has two equal singular values (principal point known). Prints the per-pair
minimum and the minimum of the median / summed cost (docs/results.md, "Accuracy at length, session 4").
"""
import numpy as np, cv2, sys
from helpers.tum import load_tum, TUM_FR3
from gsslam.config import FlowConfig
from gsslam.frontend.flow import make_flow_estimator, forward_backward_mask, textured_mask
from pathlib import Path
frames = load_tum(Path("data/rgbd_dataset_freiburg3_teddy_60"), list(range(0, 60)))
flow = make_flow_estimator(FlowConfig())
fs = np.arange(400, 700, 2.0)
c = np.array([TUM_FR3.cx, TUM_FR3.cy])
allc = []
for gap in (6, 10):
  for i in range(0, 60 - gap, 5):
    a, b = frames[i], frames[i+gap]
    fw = flow(a.image, b.image); bw = flow(b.image, a.image)
    m = forward_backward_mask(fw, bw, 1.0) & textured_mask(a.image)
    vs, us = np.nonzero(m[::4, ::4]); vs *= 4; us *= 4
    p1 = np.stack([us, vs], 1).astype(np.float64); p2 = p1 + fw[vs, us]
    F, inl = cv2.findFundamentalMat(p1, p2, cv2.FM_RANSAC, 0.5, 0.999)
    if F is None or F.shape != (3, 3): continue
    cost = []
    for f in fs:
        K = np.array([[f, 0, c[0]], [0, f, c[1]], [0, 0, 1]])
        s = np.linalg.svd(K.T @ F @ K, compute_uv=False)
        cost.append((s[0] - s[1]) / (s[0] + s[1]))
    cost = np.array(cost); allc.append(cost)
    print(gap, i, fs[np.argmin(cost)], f"{cost.min():.3f}", inl.sum(), flush=True)
allc = np.array(allc)
print("median-cost argmin", fs[np.argmin(np.median(allc, 0))], "sum", fs[np.argmin(allc.sum(0))], "true", TUM_FR3.fx)
