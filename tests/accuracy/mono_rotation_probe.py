"""Where the mono encoder's local rotation error comes from, submap by submap.

    PYTHONPATH=. python tests/accuracy/mono_rotation_probe.py RUN_DIR [--set key=value ...] [--max-submaps N]

RUN_DIR is a finished run (``gsslam run`` / ``gsslam batch``) of a mono row: its ``keyframes.tum`` gives
the keyframes, grouped into the submaps the run encoded (K + 1 frames, the first shared with the
previous submap), and its ``config.yaml`` the dataset row is re-opened from ``--seq/--kw`` (as
``drift_probe.py``). Each submap is encoded again in process, alone (no shared depth: the rotations do
not depend on it outside the degenerate case), and the probe prints, per submap, the mean / max error
(deg) of the local rotations ``R_0_i`` against the ground truth at each stage the encoder passes:

- ``tv``: the two-view (essential) rotation of the reference frame;
- ``pnp``: PnP of every frame against the triangulated frame-0 tracks (chained flow);
- ``ba``: after the bundle adjustment (the encoder's output before the dense depth);
- ``pair``: for comparison, the rotations chained from an essential matrix of each consecutive pair's own
  (unchained) flow, i - 1 -> i;
- ``out``: the encoder's final ``T_local_cam`` (what the graph receives);
- ``trans%``: its local translations after one least-squares scale, mean error / mean GT distance.

Not a test: a measuring tool (docs/results.md, "Mono local rotations, session 8").
"""

from __future__ import annotations

import argparse
import logging

import numpy as np
import yaml

from gsslam.config import load_config
from gsslam.datasets.base import open_dataset
from gsslam.frontend.encoder import pointmap_intrinsics, resize_image
from gsslam.frontend.flow import forward_backward_mask, make_flow_estimator, textured_mask
from gsslam.frontend.mono_encoder import MonoEncoder
from gsslam.frontend.pose_estimation import random_flow_matches
from gsslam.frontend.two_view import two_view_pose
from gsslam.geometry import invert_T, so3_log


def rot_err_deg(R_est: np.ndarray, R_gt: np.ndarray) -> float:
    return float(np.degrees(np.linalg.norm(so3_log(R_est.T @ R_gt))))


def pair_rotations(enc: MonoEncoder, frames, cfg) -> np.ndarray:
    """R_0_i chained from each consecutive pair's essential matrix on its own flow; [n, 3, 3] (NaN: none)."""
    intr = pointmap_intrinsics(frames[0].intrinsics, cfg.pointmap_max_side)
    imgs = [resize_image(f.image, intr) for f in frames]
    R = np.full((len(frames), 3, 3), np.nan)
    R[0] = np.eye(3)
    rng = np.random.default_rng(0)
    for i in range(1, len(frames)):
        f = enc.flow(imgs[i - 1], imgs[i])
        b = enc.flow(imgs[i], imgs[i - 1])
        ok = forward_backward_mask(f, b, 1.0, relative=0.01)
        ok &= textured_mask(imgs[i - 1], cfg.min_texture_gradient)
        uva, uvb, _ = random_flow_matches(f, ok, None, cfg.max_points_per_frame, rng)
        res = two_view_pose(intr.K, uva, uvb, cfg.ransac_threshold_px, cfg.min_inliers, 0.0)
        if res.T_b_a is None:
            break
        # R_0_i = R_0_{i-1} R_{i-1}_i ; T_b_a = T_i_{i-1}
        R[i] = R[i - 1] @ res.T_b_a[:3, :3].T
    return R


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("run_dir")
    ap.add_argument("--seq", default="../shared/data/rgbd_dataset_freiburg3_teddy")
    ap.add_argument("--dataset", default="playback")
    ap.add_argument("--kw", action="append", default=[], help="dataset kwarg key=value (value YAML)")
    ap.add_argument("--set", action="append", default=[], dest="overrides")
    ap.add_argument("--max-submaps", type=int, default=None)
    ap.add_argument("--pairs", action="store_true", help="also the consecutive-pair rotations")
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    kw = {"base": "tum", "pattern": "fbf"} if a.dataset == "playback" else {}
    for s in a.kw:
        k, v = s.split("=", 1)
        kw[k] = yaml.safe_load(v)
    ds = (
        open_dataset(a.dataset, a.seq, with_depth=False, **kw)
        if a.dataset != "playback"
        else open_dataset(a.dataset, a.seq, **kw)
    )
    ts = np.asarray(ds.timestamps())
    kf_ts = np.loadtxt(f"{a.run_dir}/keyframes.tum", comments="#", usecols=0, ndmin=1)
    kf = [int(np.argmin(np.abs(ts - t))) for t in kf_ts]
    cfg = load_config(None, ["mapper.enabled=false", *a.overrides], mode="mono")
    K1 = cfg.encoder.submap_size
    groups = [kf[s : s + K1 + 1] for s in range(0, len(kf) - K1, K1)]
    if a.max_submaps:
        groups = groups[: a.max_submaps]
    enc = MonoEncoder(cfg.encoder, make_flow_estimator(cfg.flow))
    print(f"{ds.name}: {len(kf)} keyframes, {len(groups)} submaps; {' '.join(a.overrides)}")
    print(" sub  frames     par   tv   pnp(mean/max)  ba(mean/max)  out(mean/max)  pair(mean/max)", end="")
    print("  gt rot  trans%")
    allv: dict[str, list[float]] = {"pnp": [], "ba": [], "out": [], "pair": [], "tv": [], "trans%": []}
    for si, g in enumerate(groups):
        frames = [ds[i] for i in g]
        gt = [f.T_world_cam_gt for f in frames]
        if any(x is None for x in gt):
            continue
        R_gt = [(invert_T(gt[0]) @ x)[:3, :3] for x in gt]  # R_0_i
        e = enc.encode(frames)
        m = e.meta
        row = {}
        for key in ("pnp", "ba"):
            T_i_0 = m.get(f"T_i_0_{key}")
            if T_i_0 is not None:
                row[key] = [rot_err_deg(T_i_0[i][:3, :3].T, R_gt[i]) for i in range(1, len(g))]
        row["out"] = [rot_err_deg(e.T_local_cam[i][:3, :3], R_gt[i]) for i in range(1, len(g))]
        # local translations after one least-squares scale: the error relative to the mean GT path (%)
        t_e = e.T_local_cam[1:, :3, 3]
        t_g = np.stack([(invert_T(gt[0]) @ x)[:3, 3] for x in gt[1:]])
        sc = float(np.sum(t_e * t_g) / max(np.sum(t_e * t_e), 1e-12))
        row["trans%"] = [
            100
            * float(np.mean(np.linalg.norm(sc * t_e - t_g, axis=1)) / np.mean(np.linalg.norm(t_g, axis=1)))
        ]
        ref = m.get("reference_frame")
        tv = float("nan")
        if ref is not None and m.get("T_i_0_pnp") is not None:
            tv = rot_err_deg(m["T_i_0_pnp"][ref][:3, :3].T, R_gt[ref])
        row["tv"] = [tv]
        if a.pairs:
            Rp = pair_rotations(enc, frames, cfg.encoder)
            row["pair"] = [rot_err_deg(Rp[i], R_gt[i]) for i in range(1, len(g)) if np.isfinite(Rp[i]).all()]
        for k, v in row.items():
            allv[k].extend(v)

        def mm(k, row=row):
            v = row.get(k)
            return f"{np.mean(v):5.2f}/{np.max(v):5.2f}" if v else "  -  /  -  "

        gtr = np.degrees(np.linalg.norm(so3_log(R_gt[-1])))
        print(
            f" {si:3d} {g[0]:4d}-{g[-1]:<4d} {m.get('parallax_deg', float('nan')):5.1f} {tv:5.2f} "
            f"{mm('pnp')}   {mm('ba')}   {mm('out')}   {mm('pair')}   {gtr:5.1f} {row['trans%'][0]:5.1f} "
            f"{m.get('reason', '')}"
        )
    print(
        "mean over all local poses (deg): "
        + "  ".join(f"{k} {np.mean(v):.3f} (p90 {np.percentile(v, 90):.2f})" for k, v in allv.items() if v)
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
