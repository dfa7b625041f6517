"""Measuring tool (docs/results.md, "RGB-D frames between keyframes and loops, session 11"), not a test.

One row of the tracking suite run in process as the runner runs it (map off; depth registered as
run/sequence.py does), keeping what is needed to re-pose the frames between keyframes offline
(``nearkf_split.py``): the final keyframe poses, every frame's tracked ``T_ref_cur`` (keyframes too: a
keyframe was tracked against the previous keyframe before it became one), the written frame poses, the
timestamps and ground truth. ``--back``: every non-keyframe is also tracked against the NEXT keyframe once
that exists (a second flow + joint pose, ``T_next_cur``).

    PYTHONPATH=. python3 tests/accuracy/nearkf_probe.py ROW on|off [--back] [--set k=v] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import pickle
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

import gsslam.slam.pipeline as P
from gsslam.config import load_config
from gsslam.datasets.base import open_dataset
from gsslam.frontend.tracking import FrameTracker

SUITE = Path(__file__).parents[2] / "gsslam/run/suites/tracking.yaml"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("row")
    ap.add_argument("loops")
    ap.add_argument("--back", action="store_true")
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--out", default="/tmp/nearkf")
    ap.add_argument("--data-root", default="../shared/data")
    ap.add_argument("--max-frames", type=int, default=None)
    a = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    row = next(r for r in yaml.safe_load(SUITE.read_text())["sequences"] if r["name"] == a.row)
    kw = dict(row.get("kwargs") or {})
    os.makedirs(a.out, exist_ok=True)
    if row.get("path") is None:  # a generated scene, as run/batch.py hands it to the loader
        path = Path(a.out) / f"{a.row}.yaml"
        path.write_text(yaml.safe_dump(kw, sort_keys=False))
        kw = {}
    else:
        path = str(Path(a.data_root) / row["path"])
    ds = open_dataset(row["dataset"], path, **kw)
    loops = "true" if a.loops == "on" else "false"
    cfg = load_config(None, ["mapper.enabled=false", f"loop.enabled={loops}", *a.set], mode="rgbd")
    n = min(len(ds), row.get("frames") or len(ds), a.max_frames or len(ds))
    from gsslam.frontend.depth_registration import register_frame
    from gsslam.run.registration import colour_registration

    reg, _ = colour_registration(ds, cfg, n)  # as the runner does
    if reg.is_identity():
        reg = None
    else:
        cfg = replace(cfg, encoder=replace(cfg.encoder, rgbd_icp=True))
    pipe = P.Pipeline(cfg, ds.intrinsics if reg is None else reg.colour_intrinsics(ds.intrinsics))

    tracked: dict[int, tuple[int, np.ndarray]] = {}  # every accepted track: frame -> (ref, T_ref_cur)
    back: dict[int, tuple[int, np.ndarray]] = {}  # non-keyframe -> (next keyframe, T_next_cur)
    rgbd = P.relative_rgbd

    def logged_rgbd(p, frame, matches, depth_ref, **kw):
        tr = rgbd(p, frame, matches, depth_ref, **kw)
        if tr.T_ref_cur is not None:
            tracked[frame.index] = (matches.ref_index, tr.T_ref_cur.copy())
        return tr

    P.relative_rgbd = logged_rgbd
    buffer: list = []  # the non-keyframes since the last keyframe
    add_kf = pipe._add_keyframe
    tracker_b = FrameTracker(pipe.flow, cfg.pipeline.track_points, cfg.pipeline.min_photo_consistency,
                             cfg.pipeline.blank_std, use_depth=True)  # fmt: skip

    def add_keyframe(frame):
        if a.back:
            tracker_b.set_reference(frame)
            for f in buffer:
                if f.index == frame.index or f.index not in pipe.relative:
                    continue
                _flow, m, st = tracker_b.track(f)
                if not st.ok:
                    continue
                tr = rgbd(pipe, f, m, P.frame_depth(frame), fallback=False)
                if tr.T_ref_cur is not None:
                    back[f.index] = (frame.index, tr.T_ref_cur.copy())
        buffer.clear()
        add_kf(frame)

    pipe._add_keyframe = add_keyframe
    t0 = time.time()
    for i in range(n):
        f = ds[i] if reg is None else register_frame(ds[i], reg)
        pipe.process(f)
        if f.index in pipe.relative:
            buffer.append(f)
    pipe.finish()
    P.relative_rgbd = rgbd
    gt = ds.ground_truth()
    st = dict(
        row=a.row, loops=a.loops, set=a.set, back=a.back, wall=round(time.time() - t0),
        keyframes=pipe.keyframe_poses(), frames=pipe.frame_poses(), relative=dict(pipe.relative),
        tracked=tracked, back_tracked=back, ts=dict(pipe.timestamps),
        gt_t=np.asarray(gt.timestamps), gt_T=np.asarray(gt.poses), keyframe_order=list(pipe.keyframe_order),
        loops_metrics=pipe.loop_stage.metrics(), chains=len(pipe.chains),
    )  # fmt: skip
    tag = f"{a.row}_{a.loops}{'_back' if a.back else ''}"
    with open(f"{a.out}/{tag}.pkl", "wb") as fh:
        pickle.dump(st, fh)
    print(json.dumps({"row": a.row, "loops": a.loops, "wall": st["wall"], "frames": len(st["frames"]),
                      "keyframes": len(st["keyframes"]), "back": len(back)}))  # fmt: skip


main()
