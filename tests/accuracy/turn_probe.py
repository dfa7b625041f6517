"""What happens to a mono chain across a rotation-dominated turn: one line per submap.

    PYTHONPATH=. python tests/accuracy/turn_probe.py --start 250 --frames 200 [--loops on] [--set k=v ...]

Plays the long synthetic room's noise-free twin (``synth_room1000``, true focal; its exact depth and
poses are the reference) in process, map off, from ``--start`` for ``--frames`` frames, and prints per
submap of every chain: its keyframes, the encoder's verdict (``meta["reason"]``, placeholder depth),
``r`` (the submap's local translations against the ground truth's: its translation scale as chained),
``d0`` / ``dK`` (its frame-0 / frame-K depth against the true depth, same units), ``rot`` (mean local
rotation error, deg), ``W`` (the graph's Sim(3) scale of the submap x ``r``: the world scale of its
translations; constant along a chain that holds its scale), then the Sim(3) ATE of the run's keyframes
and of all frames. Not a test: a measuring tool (docs/results.md, "Mono across turns, session 13").
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

ROOM = dict(n_frames=1000, width=320, height=240, scene="furnished_room", trajectory="room_walk", seed=0)
KINECT_DEGRADE = dict(shutter=0.5, exposure_amp=0.25, exposure_period=150)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--start", type=int, default=250)
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--loops", choices=["on", "off"], default="on")
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    ap.add_argument(
        "--twin",
        choices=["sharp", "kinect"],
        default="sharp",
        help="kinect: the Kinect twin's colour (motion blur + exposure swings of synth_room1000_kinect)",
    )
    ap.add_argument("--focal", type=float, default=1.0, help="hand out the true focal times this")
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)

    from chain_links import per_submap

    from gsslam.config import load_config
    from gsslam.datasets.base import loader
    from gsslam.eval.ate import compute_ate
    from gsslam.slam.pipeline import Pipeline
    from gsslam.types import Trajectory

    kw = dict(ROOM, focal_scale=a.focal)
    if a.twin == "kinect":  # colour as synth_room1000_kinect's (its depth is not read in mono; exact here)
        kw["degrade"] = KINECT_DEGRADE
    ds = loader("synthetic")(None, **kw)
    loops = "true" if a.loops == "on" else "false"
    cfg = load_config(None, ["mapper.enabled=false", f"loop.enabled={loops}", *a.overrides], mode="mono")
    pipe = Pipeline(cfg, ds.intrinsics)
    gt_depth = {}
    import cv2

    for i in range(a.start, min(a.start + a.frames, len(ds))):
        f = ds[i]
        gt_depth[f.index] = f.depth
        pipe.process(dataclasses.replace(f, depth=None))
    pipe.finish()
    gt = ds.ground_truth()
    for cid, ch in enumerate(pipe.chains):
        encs = ch.encodings
        if not encs:
            continue

        def small(fi, shape):
            d = gt_depth.get(fi)
            return None if d is None else cv2.resize(np.asarray(d, np.float32), shape[::-1], interpolation=0)

        st = {
            "gt": gt,
            "ts": pipe.timestamps,
            "frame_indices": [list(e.frame_indices) for e in encs],
            "T_local_cam": [e.T_local_cam for e in encs],
            "depth0": [e.points_cam[0, ..., 2] for e in encs],
            "depthK": [e.points_cam[-1, ..., 2] for e in encs],
            "meta": [e.meta for e in encs],
        }
        st["gt_depth0"] = [small(fi[0], d.shape) for fi, d in zip(st["frame_indices"], st["depth0"])]
        st["gt_depthK"] = [small(fi[-1], d.shape) for fi, d in zip(st["frame_indices"], st["depthK"])]
        rows = per_submap(st)
        scales = ch.graph.submap_scales()
        print(f"chain {cid}: {len(encs)} submaps, T_world_chain scale {ch.scale:.3f}, in_world {ch.in_world}")
        print("  sub frames      reason                     r      d0     dK    rot    W")
        for k, (e, row) in enumerate(zip(encs, rows)):
            reason = e.meta.get("reason", "") + (" PH" if e.meta.get("placeholder_depth") else "")
            print(
                f"  {k:3d} {e.frame_indices[0]:4d}-{e.frame_indices[-1]:<4d} {reason:24s} {row['r']:7.3f} "
                f"{row['d0']:6.3f} {row['dK']:6.3f} {row['rot']:5.2f} {scales[k] * row['r']:6.3f}"
            )
    ev = {}
    for e in pipe.events:
        ev[e.kind] = ev.get(e.kind, 0) + 1
    kf = pipe.keyframe_poses()
    fr = pipe.frame_poses()
    for name, P in (("keyframes", kf), ("all frames", fr)):
        ks = sorted(P)
        tr = Trajectory(np.array([pipe.timestamps[k] for k in ks]), np.stack([P[k] for k in ks]))
        res, al = compute_ate(gt, tr, align="sim3")
        print(f"ATE {name} (Sim(3)): {100 * res.stats.rmse:.2f} cm")
    print(f"events {ev}; loops {pipe.loop_stage.metrics()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
