"""Measure the encoders' local-pose accuracy on TUM fr3/teddy (a script, not a test).

    PYTHONPATH=tests python tests/frontend/measure_local_accuracy.py [TUM folder] [--frames N] [--mode M]

Selects keyframes with the flow keyframe rule, cuts submaps of K+1 keyframes sharing one frame,
encodes each and prints, per submap, the mean relative translation / rotation error of the
frames w.r.t. frame 0 against ground truth (mono: after a per-submap least-squares scale).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from gsslam.config import FlowConfig, KeyframeConfig, load_config
from gsslam.frontend.encoder import make_encoder
from gsslam.frontend.flow import make_flow_estimator
from gsslam.frontend.keyframes import KeyframeSelector
from gsslam.frontend.local_accuracy import local_pose_errors
from helpers.tum import load_tum


def select_keyframes(frames, flow, selector) -> list[int]:
    kfs = [0]
    for j in range(1, len(frames)):
        fl = flow(frames[kfs[-1]].image, frames[j].image)
        if selector.is_keyframe(fl, j - kfs[-1]):
            kfs.append(j)
    return kfs


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument(
        "root",
        nargs="?",
        default=str(Path(__file__).resolve().parents[2] / "data" / "rgbd_dataset_freiburg3_teddy_60"),
    )
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--mode", default="rgbd")
    ap.add_argument("--set", action="append", default=[], help="encoder override, e.g. rgbd_odometry=false")
    ap.add_argument("--start", type=int, default=5, help="first frame (TUM teddy: GT starts at frame 5)")
    args = ap.parse_args()
    root = Path(args.root)
    n = sum(1 for line in (root / "rgb.txt").read_text().splitlines() if line and not line.startswith("#"))
    frames = load_tum(root, list(range(args.start, min(n, args.frames))))
    fcfg = FlowConfig()
    ecfg = load_config(overrides=[f"encoder.{kv}" for kv in args.set]).encoder
    flow = make_flow_estimator(fcfg)
    kfs = select_keyframes(frames, flow, KeyframeSelector(KeyframeConfig()))
    enc = make_encoder(args.mode, ecfg, flow)
    K = ecfg.submap_size
    all_t, all_r = [], []
    t0 = time.time()
    for s0 in range(0, len(kfs) - 1, K):
        ids = kfs[s0 : s0 + K + 1]
        sub = [frames[i] for i in ids]
        if len(sub) < 2 or any(f.T_world_cam_gt is None for f in sub):
            continue
        e = enc.encode(sub)
        gt = np.stack([f.T_world_cam_gt for f in sub])
        te, re, sc = local_pose_errors(e.T_local_cam, gt, align_scale=args.mode == "mono")
        span = np.linalg.norm((np.linalg.inv(gt[0]) @ gt[-1])[:3, 3])
        all_t += list(te)
        all_r += list(re)
        flags = {k: e.meta.get(k) for k in ("degenerate", "direct_rejected", "pnp_failed")}
        print(
            f"submap frames {[f.index for f in sub]} span {span * 100:.1f} cm: "
            f"mean t {te.mean() * 100:.2f} cm "
            f"(max {te.max() * 100:.2f}), mean r {re.mean():.3f} deg (max {re.max():.3f}) scale {sc:.3f} "
            f"flags {flags}"
        )
    print(
        f"{args.mode}: {len(kfs)} keyframes, overall mean t {np.mean(all_t) * 100:.2f} cm, "
        f"mean r {np.mean(all_r):.3f} deg, encode time {time.time() - t0:.1f} s"
    )


if __name__ == "__main__":
    main()
