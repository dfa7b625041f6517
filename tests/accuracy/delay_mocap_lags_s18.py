"""Which camera is late on the real TUM fr3/teddy: the colour camera's (flow) and the depth camera's (ICP)
rotation series over pairs (k, k + 2), each fitted against the 100 Hz mocap's over the same pairs shifted by a
lag L (the mocap's rotation over [t_a + L, t_b + L], the mocap-to-camera turn fitted once, a scale per axis;
the lag of least RMS, block-bootstrap sd). Over the whole image and per band of image rows (a rolling
shutter: each band's rows are read at their own time). Not a test: a measuring tool (docs/results.md,
"The delay estimate on real data, session 18").

    PYTHONPATH=. python3 tests/accuracy/delay_mocap_lags_s18.py [--frames 140] [--bands 3]

A negative lag: the series follows the mocap that much earlier than the images' stamps (the mocap's own clock
offset is common to both cameras; their difference is what the delay estimate sees).
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from gsslam.config import FlowConfig
from gsslam.datasets import open_dataset
from gsslam.frontend.colour_focal import flow_pairs
from gsslam.frontend.flow import make_flow_estimator
from gsslam.frontend.registration_delay import band_rows
from gsslam.frontend.registration_handeye import colour_motion, depth_motion
from gsslam.geometry import so3_log

TEDDY = "/work/shared/data/rgbd_dataset_freiburg3_teddy"
LAGS = np.arange(-0.06, 0.0605, 0.002)


def mocap_rotations(slerp: Slerp, ta: np.ndarray, tb: np.ndarray) -> np.ndarray:  # [N, 3] T_b_a's rotation
    return (slerp(tb).inv() * slerp(ta)).as_rotvec()


def align(M: np.ndarray, X: np.ndarray) -> np.ndarray:  # the rotation R with X ~ s R M (Kabsch)
    U, _, Vt = np.linalg.svd(M.T @ X)
    return Vt.T @ np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))]) @ U.T


def lag(slerp, ta, tb, X, R, idx=None) -> float:
    idx = np.arange(len(X)) if idx is None else idx
    rms = []
    for L in LAGS:
        MR = mocap_rotations(slerp, ta[idx] + L, tb[idx] + L) @ R.T
        s = np.sum(MR * X[idx], 0) / np.sum(MR * MR, 0)  # a scale per axis
        rms.append(float(np.sqrt(np.mean((X[idx] - s * MR) ** 2))))
    i = int(np.clip(np.argmin(rms), 1, len(LAGS) - 2))
    y0, y1, y2 = rms[i - 1 : i + 2]
    den = y0 - 2 * y1 + y2
    return float(LAGS[i] + (0.5 * (y0 - y2) / den if den > 0 else 0.0) * (LAGS[1] - LAGS[0]))


def lag_with_sd(slerp, ta, tb, X, R, boot: int = 30, block: int = 10) -> tuple[float, float]:
    rng = np.random.default_rng(0)
    n = len(X)
    samples = []
    for _ in range(boot):
        starts = rng.integers(0, n - block, n // block + 1)
        idx = np.concatenate([np.arange(s, s + block) for s in starts])[:n]
        samples.append(lag(slerp, ta, tb, X, R, idx))
    return lag(slerp, ta, tb, X, R), float(np.std(samples))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=140)
    ap.add_argument("--bands", type=int, default=3)
    a = ap.parse_args()
    ds = open_dataset("tum", TEDDY)
    frames = [ds[i] for i in range(min(a.frames, len(ds)))]
    intr = frames[0].intrinsics
    gt = ds.ground_truth()
    slerp = Slerp(gt.timestamps, Rotation.from_matrix(gt.poses[:, :3, :3]))
    flow = make_flow_estimator(FlowConfig(dis_preset="medium", max_side=320))
    pairs = flow_pairs(frames, flow, gap=2, max_pairs=len(frames), min_rotation_deg=0.0, icp_refused_ok=True)
    t = np.array([f.timestamp for f in frames])
    pairs = [p for p in pairs if t[p.index_a] - 0.07 > gt.timestamps[0]]  # the mocap starts after frame 4
    names = ["whole image"] + [f"rows {r0:.0f}-{r1:.0f}" for r0, r1 in band_rows(intr, intr, a.bands)]
    series: dict[str, list] = {n: [[], []] for n in names}
    kept = []
    for p in pairs:
        cm = colour_motion(p, intr, (intr.fx, intr.fy), 0.0, p.T_b_a)
        dm = depth_motion(p.raw_a, p.raw_b, intr, p.T_b_a)
        if cm is None or dm is None:
            continue
        per = [(cm, dm)]
        for r0, r1 in band_rows(intr, intr, a.bands):
            sel = (p.uv_a[:, 1] >= r0) & (p.uv_a[:, 1] < r1)
            src = np.array(p.raw_a, np.float32)
            src[: int(np.ceil(r0))], src[int(np.ceil(r1)) :] = np.nan, np.nan
            band = replace(p, uv_a=p.uv_a[sel], uv_b=p.uv_b[sel])
            per.append(
                (
                    colour_motion(band, intr, (intr.fx, intr.fy), 0.0, cm[0]),
                    depth_motion(src, p.raw_b, intr, dm[0]),
                )
            )
        if any(c is None or d is None for c, d in per):
            continue
        kept.append(p)
        for n, (c, d) in zip(names, per):
            series[n][0].append(so3_log(c[0][:3, :3]))
            series[n][1].append(so3_log(d[0][:3, :3]))
    ta, tb = t[[p.index_a for p in kept]], t[[p.index_b for p in kept]]
    C0 = np.array(series[names[0]][0])
    R = align(mocap_rotations(slerp, ta, tb), C0)  # the mocap-to-camera turn, from the whole image's flow
    print(f"teddy frames 0-{len(frames) - 1}: {len(kept)} pairs; mocap-to-camera turn "
          f"{np.degrees(np.linalg.norm(so3_log(R))):.2f} deg")  # fmt: skip
    for n in names:
        (lc, sc), (ld, sdd) = (lag_with_sd(slerp, ta, tb, np.array(x), R) for x in series[n])
        print(f"{n:14s} colour (flow) {1000 * lc:6.1f} ms (sd {1000 * sc:.1f})   depth (ICP) "
              f"{1000 * ld:6.1f} ms (sd {1000 * sdd:.1f})   depth - colour {1000 * (ld - lc):6.1f} ms",
              flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
