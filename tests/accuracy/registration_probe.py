"""Probe (not a test): the reprojection cost over colour focal a and depth focal b (relative to the given fx),
the ICP residual over b, and a baseline scan, on the first 40 frames of teddy (docs/results.md, "RGB-D
accuracy, session 5"). The depth-given and colour-given hypotheses are the lines b = 1 and a = 1.

    PYTHONPATH=. python tests/accuracy/registration_probe.py colour|depth|plain

colour: simulated Kinect v1 depth (k 1.114, baseline 2.5 cm) with the colour intrinsics handed out;
depth: the same with the depth intrinsics (7-Scenes); plain: registered TUM.
"""

import sys
from dataclasses import replace

import numpy as np

from gsslam.config import FlowConfig
from gsslam.datasets.base import open_dataset
from gsslam.frontend.encoder import depth_edge_mask
from gsslam.frontend.flow import forward_backward_mask, make_flow_estimator, textured_mask
from gsslam.frontend.icp import TRACK_STRIDES, icp_point_to_plane
from gsslam.geometry import so3_log

case = sys.argv[1]
KW = dict(base="tum", pattern="f")
if case == "colour":
    KW["misregister"] = {"baseline_m": 0.025, "focal_scale": 1.114}
if case == "depth":
    KW["misregister"] = {"baseline_m": 0.025, "focal_scale": 1.114, "report": "depth"}
if case == "colour0":
    KW["misregister"] = {"baseline_m": 0.0, "focal_scale": 1.114}
ds = open_dataset("playback", "../shared/data/rgbd_dataset_freiburg3_teddy", **KW)
frames = [ds[i] for i in range(40)]
intr = frames[0].intrinsics
flow = make_flow_estimator(FlowConfig())
rng = np.random.default_rng(0)
pairs = []
for i in range(0, 36, 2):
    fa, fb = frames[i], frames[i + 4]
    if fa.depth is None or fb.depth is None:
        continue
    icp = icp_point_to_plane(fa.depth, fb.depth, intr, np.eye(4), strides=TRACK_STRIDES + (4,))
    if not icp.ok or np.degrees(np.linalg.norm(so3_log(icp.T_tgt_src[:3, :3]))) < 1.0:
        continue
    fw = flow(fa.image, fb.image)
    bw = flow(fb.image, fa.image)
    valid = forward_backward_mask(fw, bw, 1.0) & textured_mask(fa.image)
    g = np.zeros_like(valid)
    g[3::6, 3::6] = True
    vs, us = np.nonzero(valid & g)
    if len(us) > 3000:
        keep = rng.choice(len(us), 3000, replace=False)
        vs, us = vs[keep], us[keep]
    uv_a = np.stack([us, vs], 1).astype(float)
    uv_b = uv_a + fw[vs, us]
    dep = np.where(depth_edge_mask(fa.depth), np.nan, fa.depth).astype(float)
    pairs.append(dict(uv_a=uv_a, uv_b=uv_b, dep=dep, da=fa.depth, db=fb.depth))
    if len(pairs) >= 12:
        break
print(case, "pairs", len(pairs), "given fx", intr.fx)
c = np.array([intr.cx, intr.cy])
bs = np.round(np.arange(0.96, 1.221, 0.02), 3)
icps = {}
for b in bs:
    ib = replace(intr, fx=intr.fx * b, fy=intr.fy * b)
    Ts, rm = [], []
    for p in pairs:
        r = icp_point_to_plane(p["da"], p["db"], ib, np.eye(4), strides=TRACK_STRIDES + (4,))
        Ts.append(r.T_tgt_src)
        rm.append(r.rmse_m)
    icps[b] = (Ts, rm)
    print(f"b={b:.2f} icp rmse mean {1000 * np.mean(rm):.3f} mm ok")


def cost(a, b, bx=0.0):
    fc = np.array([intr.fx, intr.fy]) * a
    fd = np.array([intr.fx, intr.fy]) * b
    Ts = icps[b][0]
    tot = cnt = 0
    for p, T in zip(pairs, Ts):
        h, w = p["dep"].shape
        z = np.full(len(p["uv_a"]), 1.5)
        for _ in range(3):
            xn = (p["uv_a"] - c) / fc  # normalized colour ray
            pd = c + fd * (xn * z[:, None] - np.array([bx, 0])) / z[:, None]
            pd = np.rint(pd).astype(int)
            inside = (pd[:, 0] >= 0) & (pd[:, 0] < w) & (pd[:, 1] >= 0) & (pd[:, 1] < h)
            zz = np.full(len(pd), np.nan)
            zz[inside] = p["dep"][pd[inside, 1], pd[inside, 0]]
            if bx == 0:
                z = zz
                break
            z = np.where(np.isfinite(zz), zz, 1.5)
        z = zz
        ok = np.isfinite(z) & (z > 0)
        Xc = np.concatenate([xn[ok] * z[ok, None], z[ok, None]], 1)
        Xd = Xc - np.array([bx, 0, 0])
        Xdb = Xd @ T[:3, :3].T + T[:3, 3]
        Xcb = Xdb + np.array([bx, 0, 0])
        uv = c + fc * Xcb[:, :2] / Xcb[:, 2:3]
        e = np.linalg.norm(uv - p["uv_b"][ok], axis=1)
        tot += np.minimum(e, 4.0).sum()
        cnt += ok.sum()
    return tot / cnt


res = {}
for b in bs:
    ks = np.arange(0.85, 1.25, 0.005)
    cs = np.array([cost(b / k, b) for k in ks])
    j = int(np.argmin(cs))
    res[b] = (ks[j], cs[j])
    print(f"b={b:.2f}: best k={ks[j]:.3f} (a={b / ks[j]:.3f}) cost {cs[j]:.4f}")
# baseline scan at the best b
bbest = min(res, key=lambda b: res[b][1])
kb = res[bbest][0]
for bx in [-0.05, -0.025, 0.0, 0.025, 0.05]:
    ks = np.arange(kb - 0.05, kb + 0.05, 0.005)
    cs = np.array([cost(bbest / k, bbest, bx) for k in ks])
    j = int(np.argmin(cs))
    print(f"b={bbest} bx={bx}: best k={ks[j]:.3f} cost {cs[j]:.4f}")
