"""Why RGB-D tracking fails: a per-frame log of the tracker on a (degraded) teddy playback.

    PYTHONPATH=. python tests/accuracy/track_probe.py [--stride 2] [--pattern fbfbf] [--max-frames 300] \
        [--loops off] [--set key=value ...] [--row teddy200_fbf_7scenes] [--dump run.npz]

Runs the pipeline in process (map off, RGB-D) on teddy played ``stride`` times faster with motion blur and
exposure swings (the ``teddy200_s2_blur`` row; ``--row``: any playback or TUM row of the tracking suite)
and prints ATE (all frames / keyframes / the others), the
events, then one JSON line per tracking attempt: frame ``f`` and keyframe ``ref``, the tracker's
photo-consistency ``pc`` and median flow ``med`` (px), the exposure gain ratio keyframe -> frame ``gain``,
the RGB-D step's ``source`` (pnp / icp / "" failed), PnP inliers / matches, ICP fitness, the ground-truth
motion keyframe -> frame and the error of the tracked pose. Not a test: a measuring tool
(docs/results.md, "RGB-D tracking under blur, session 7").
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
from collections import Counter
from pathlib import Path

import numpy as np

import gsslam.slam.pipeline as P
from gsslam.config import load_config
from gsslam.datasets.base import open_dataset
from gsslam.eval.ate import ate_from_pairs
from gsslam.frontend.depth_registration import (
    IDENTITY,
    DepthRegistration,
    register_frame,
    registration_correction,
)
from gsslam.frontend.flow import make_flow_estimator
from gsslam.geometry import invert_T, so3_log


def _motion(T: np.ndarray) -> tuple[float, float]:  # -> (cm, deg)
    deg = float(np.degrees(np.linalg.norm(so3_log(T[:3, :3]))))
    return round(100 * float(np.linalg.norm(T[:3, 3])), 2), round(deg, 2)


def _row(name: str) -> tuple[str, dict, int | None]:  # -> (dataset, kwargs, frames)
    import yaml

    suite = Path(__file__).resolve().parents[2] / "gsslam" / "run" / "suites" / "tracking.yaml"
    for row in yaml.safe_load(suite.read_text())["sequences"]:
        if row["name"] == name and row.get("dataset") in ("playback", "tum"):
            return row["dataset"], dict(row.get("kwargs", {})), row.get("frames")
    raise SystemExit(f"no playback or tum row {name!r} in {suite}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seq", default="../shared/data/rgbd_dataset_freiburg3_teddy")
    ap.add_argument("--stride", type=int, default=2)
    ap.add_argument("--pattern", default="fbfbf")
    ap.add_argument("--no-degrade", action="store_true")
    ap.add_argument("--loops", default="off")
    ap.add_argument("--set", action="append", default=[], dest="overrides")
    ap.add_argument("--max-frames", type=int, default=300)
    ap.add_argument("--row", default=None, help="a playback or TUM row of gsslam/run/suites/tracking.yaml")
    ap.add_argument("--dump", default=None, help="write per-frame poses, keyframes and attempts (.npz)")
    ap.add_argument("--reg", default=None, help="K,B,GIVEN: apply this registration, no estimate")
    ap.add_argument("--no-force-icp", action="store_true", help="keep encoder.rgbd_icp as configured")
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    if a.row is not None:
        kind, kw, frames = _row(a.row)
        ds = open_dataset(kind, a.seq, **kw)
        a.max_frames = frames or len(ds)
    else:
        degrade = None if a.no_degrade else {"shutter": 0.5, "exposure_amp": 0.25, "exposure_period": 150}
        ds = open_dataset("playback", a.seq, base="tum", pattern=a.pattern, stride=a.stride, degrade=degrade)
    loops = "true" if a.loops == "on" else "false"
    cfg = load_config(None, ["mapper.enabled=false", f"loop.enabled={loops}", *a.overrides], mode="rgbd")
    reg = IDENTITY  # as the runner (gsslam.run.sequence): unregistered depth re-projected into colour
    if cfg.encoder.colour_focal_auto and a.reg is None:
        first = [ds[i] for i in range(min(len(ds), cfg.encoder.colour_focal_frames, a.max_frames))]
        reg, _ = registration_correction(
            first, make_flow_estimator(cfg.flow), min_dev=cfg.encoder.colour_focal_min_dev,
            min_baseline_m=cfg.encoder.colour_focal_min_baseline_m,
            min_gain=cfg.encoder.colour_focal_min_gain,
            fallback_gap=cfg.encoder.colour_focal_fallback_gap or None,
        )  # fmt: skip
    if a.reg is not None:
        k, b, given = a.reg.split(",")
        reg = DepthRegistration(float(k), float(b), given, ok=True)
    if not reg.is_identity() and not a.no_force_icp:
        cfg = dataclasses.replace(cfg, encoder=dataclasses.replace(cfg.encoder, rgbd_icp=True))
    pipe = P.Pipeline(cfg, reg.colour_intrinsics(ds.intrinsics))
    gt: dict[int, np.ndarray | None] = {}
    rec: list[dict] = []
    track, rgbd = pipe.tracker.track, P.relative_rgbd

    def logged_track(frame):
        flow, m, st = track(frame)
        ref = pipe.tracker.ref
        d = {"f": frame.index, "ref": ref.index, "ok": st.ok, "reason": st.reason}
        d.update(pc=round(st.photo_consistency, 3), med=round(st.median_flow_px, 1))
        if getattr(ds, "degradation", None) is not None:
            d["gain"] = round(ds.degradation.gain(frame.index) / ds.degradation.gain(ref.index), 3)
        if gt.get(ref.index) is not None and gt.get(frame.index) is not None:
            d["gt_cm"], d["gt_deg"] = _motion(invert_T(gt[ref.index]) @ gt[frame.index])
        rec.append(d)
        return flow, m, st

    def logged_rgbd(p, frame, matches, depth_ref, **kw):
        tr = rgbd(p, frame, matches, depth_ref, **kw)
        d = rec[-1]
        d.update(source=tr.source, inliers=tr.pnp_inliers, matches=tr.pnp_matches)
        d["fitness"] = round(tr.icp_fitness, 3)
        if tr.T_ref_cur is not None and "gt_cm" in d:
            G = invert_T(gt[matches.ref_index]) @ gt[matches.cur_index]
            d["err_cm"], d["err_deg"] = _motion(invert_T(G) @ tr.T_ref_cur)
        return tr

    metas: list[dict] = []
    encode = pipe.encoder.encode

    def logged_encode(frames, **kw):
        enc = encode(frames, **kw)
        m = enc.meta
        metas.append({"use_icp": m.get("use_icp"), "ratio": m.get("pnp_icp_rotation_ratio"),
                      "joint": len(m.get("joint_posed", [])), "n": len(frames) - 1})  # fmt: skip
        return enc

    pipe.encoder.encode = logged_encode
    pipe.tracker.track = logged_track
    P.relative_rgbd = logged_rgbd  # the pipeline calls it by this module-level name
    n = min(a.max_frames, len(ds))
    for i in range(n):
        f = register_frame(ds[i], reg)
        gt[f.index] = f.T_world_cam_gt
        pipe.process(f)
    pipe.finish()
    P.relative_rgbd = rgbd
    est = pipe.frame_poses()
    idx = [i for i in sorted(est) if gt.get(i) is not None]
    P_g = np.array([gt[i][:3, 3] for i in idx])
    res = ate_from_pairs(P_g, np.array([est[i][:3, 3] for i in idx]), "se3")
    e = np.linalg.norm(res.alignment.apply_positions(np.array([est[i][:3, 3] for i in idx])) - P_g, axis=1)
    kf = np.array([i in pipe.keyframes for i in idx])
    rms = lambda x: 100 * float(np.sqrt(np.mean(x**2))) if len(x) else float("nan")  # noqa: E731
    print(f"{ds.name}: {n} frames; ATE {100 * res.stats.rmse:.3f} cm over {len(idx)} frames; "
          f"keyframes {rms(e[kf]):.3f} ({int(kf.sum())}), others {rms(e[~kf]):.3f}")  # fmt: skip
    print("events:", dict(Counter(ev.kind for ev in pipe.events)), "ICP-tracked:", pipe.n_icp_tracked)
    print("registration:", reg, "loops:", pipe.loop_stage.metrics())
    print("submaps (use_icp, PnP/ICP rotation ratio, joint-posed / keyframes):",
          [(d["use_icp"], round(d["ratio"], 3), f'{d["joint"]}/{d["n"]}') for d in metas])  # fmt: skip
    for ev in pipe.events:
        print("  ", ev.frame_index, ev.kind, ev.detail[:80])
    for d in rec:
        print(json.dumps(d))
    if a.dump:
        np.savez(
            a.dump,
            idx=np.array(idx),
            est=np.array([est[i] for i in idx]),
            gt=np.array([gt[i] for i in idx]),
            err=e,
            keyframes=np.array(sorted(pipe.keyframes)),
            records=json.dumps(rec),
            ref=np.array([pipe.relative[i][0] if i in pipe.relative else -1 for i in idx]),
            events=json.dumps([(ev.frame_index, ev.kind) for ev in pipe.events]),
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
