"""Where drift starts: per submap, the encoder's local scale against the ground truth along the chain.

    PYTHONPATH=. python tests/accuracy/drift_probe.py --mode mono --loops off --kw stride=2 \
        --kw pattern=fbfbf --kw degrade='{"shutter":0.5,"exposure_amp":0.25,"exposure_period":150}' \
        [--max-frames N] [--set key=value ...]

Runs the pipeline in process (map off) on a teddy playback and prints, per submap of each chain:
its keyframes, the encoder's scale source and dense correction, the two-view parallax, PnP failures,
``enc/gt`` (the least-squares ratio of the encoder's local keyframe translations to the ground truth's,
in the chain's units: the submap's scale as chained through the shared frames, before the graph),
``link`` (its ratio to the previous submap's: the error of one chaining step), ``graph`` (the same
with the final graph's Sim(3) scale of the submap applied: what the trajectory gets) and the mean
keyframe rotation error of the local poses. Then the events. Not a test: a measuring tool
(docs/results.md, "Drift on harder sequences, session 6").
"""

from __future__ import annotations

import argparse
import logging
from collections import Counter

import numpy as np
import yaml

from gsslam.config import load_config
from gsslam.datasets.base import open_dataset
from gsslam.eval.ate import ate_from_pairs
from gsslam.geometry import invert_T, so3_log
from gsslam.slam.pipeline import Pipeline


def local_scale(enc, gt: dict) -> tuple[float, float]:
    """LS ratio |t_enc| / |t_gt| of the keyframes' local translations, and the mean rotation error (deg)."""
    G0 = gt.get(enc.frame_indices[0])
    if G0 is None:
        return float("nan"), float("nan")
    num = den = 0.0
    rerr = []
    for j, f in enumerate(enc.frame_indices[1:], 1):
        if gt.get(f) is None:
            continue
        Tg = invert_T(G0) @ gt[f]
        Te = enc.T_local_cam[j]
        num += np.linalg.norm(Te[:3, 3]) * np.linalg.norm(Tg[:3, 3])
        den += np.linalg.norm(Tg[:3, 3]) ** 2
        rerr.append(np.degrees(np.linalg.norm(so3_log(Te[:3, :3].T @ Tg[:3, :3]))))
    return (num / den if den > 0 else float("nan")), (float(np.mean(rerr)) if rerr else float("nan"))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seq", default="../shared/data/rgbd_dataset_freiburg3_teddy")
    ap.add_argument("--mode", default="mono")
    ap.add_argument("--loops", default="off")
    ap.add_argument("--kw", action="append", default=[], help="playback kwarg key=value (value YAML)")
    ap.add_argument("--set", action="append", default=[], dest="overrides")
    ap.add_argument("--max-frames", type=int, default=None)
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    kw = {"base": "tum", "pattern": "fbf"}
    for s in a.kw:
        k, v = s.split("=", 1)
        kw[k] = yaml.safe_load(v)
    ds = open_dataset("playback", a.seq, **kw)
    loops = "true" if a.loops == "on" else "false"
    overrides = ["mapper.enabled=false", f"loop.enabled={loops}", *a.overrides]
    cfg = load_config(None, overrides, mode=a.mode)
    pipe = Pipeline(cfg, ds.intrinsics)
    n = len(ds) if a.max_frames is None else min(a.max_frames, len(ds))
    gt = {}
    for i in range(n):
        f = ds[i]
        gt[f.index] = f.T_world_cam_gt
        pipe.process(f)
    pipe.finish()
    print(f"{ds.name}: {n} frames, {a.mode}, loops {a.loops}, {len(pipe.chains)} chain(s)")
    for cid, chain in enumerate(pipe.chains):
        scales = chain.graph.submap_scales() if chain.encodings and not chain.failed else None
        prev = None
        print(f"chain {cid}: {len(chain.encodings)} submaps, in_world={chain.in_world} failed={chain.failed}")
        print(" sub  frames      source/reason               g2     par  pnpF  enc/gt   link  graph  rot")
        for i, enc in enumerate(chain.encodings):
            r, rot = local_scale(enc, gt)
            link = r / prev if prev and np.isfinite(prev) else float("nan")
            gr = r * scales[i] if scales is not None and i < len(scales) else float("nan")
            m = enc.meta
            g2, par = m.get("dense_scale_correction", float("nan")), m.get("parallax_deg", float("nan"))
            src = m.get("scale_source", "") + ("/" + m["reason"] if m.get("reason", "ok") != "ok" else "")
            print(
                f" {i:3d} {enc.frame_indices[0]:4d}-{enc.frame_indices[-1]:<4d} {src:28s} "
                f"{g2:6.3f} {par:5.1f} "
                f"{len(m.get('pnp_failed', [])):4d} {r:7.3f} {link:6.3f} {gr:6.3f} {rot:5.2f}"
            )
            prev = r
    est = pipe.frame_poses()
    idx = [i for i in sorted(est) if gt.get(i) is not None]
    P_e = np.array([est[i][:3, 3] for i in idx])
    P_g = np.array([gt[i][:3, 3] for i in idx])
    res = ate_from_pairs(P_g, P_e, "sim3" if a.mode == "mono" else "se3")
    res3 = ate_from_pairs(P_g, P_e, "sim3")
    print(f"ATE {100 * res.stats.rmse:.2f} cm, {len(idx)} frames; Sim(3) scale {res3.alignment.scale:.4f}")
    e = np.linalg.norm(res.alignment.apply_positions(P_e) - P_g, axis=1)
    w = np.array(idx) // 100
    by = " ".join(f"{k * 100}:{100 * e[w == k].mean():.1f}" for k in np.unique(w))
    print("error cm by 100 frames:", by)
    print("events:", dict(Counter(e.kind for e in pipe.events)))
    for e in pipe.events[:15]:
        print("  ", e.frame_index, e.kind, e.detail[:100])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
