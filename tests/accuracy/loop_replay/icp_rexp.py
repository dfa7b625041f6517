"""Replay an RGB-D run kept by ``exp.py --keep-depth`` with its loop factors replaced (docs/results.md,
"RGB-D loops with ICP, session 6"): as is, no loops, point sigma from the loop's inlier RMS, or the
ICP relative-pose factor (gsslam.loop.icp_loop) at several effective point counts.
Usage: ``PYTHONPATH=. python icp_rexp.py PKL [variant ...]``; variants: asis off rms sig=S icp=N_EFF
icp=N_EFF,huber=H icpx=N_EFF (ICP factor added next to the point factor)."""
import dataclasses, pickle, sys
import numpy as np
sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))  # replay.py
import replay as rp
from gsslam.config import LoopConfig, load_config
from gsslam.geometry import depth_to_points
from gsslam.graph.keys import submap_key
from gsslam.loop.icp_loop import refine_loop_icp
from gsslam.loop.types import LoopConstraint
from gsslam.loop.weights import inlier_rms
from gsslam.types import SubmapEncoding

st = pickle.load(open(sys.argv[1], "rb"))
encs = []
for fi, L, D, intr in zip(st["frame_indices"], st["T_local_cam"], st["enc_depth"], st["enc_intr"]):
    P = np.stack([depth_to_points(intr.K, d.astype(np.float64)) for d in D])
    encs.append(SubmapEncoding(list(fi), L, P, np.isfinite(P[..., 2]).astype(float), intr))
key_of = {submap_key(k): k for k in range(len(encs))}
lcs = {(d["i"], d["m"]): LoopConstraint(d["i"], d["m"], d["X_i"], d["X_m"], d["T_i_m"], 0.0, 0.0, d["thr"]) for d in st["loopc"]}
_cache = {}

def icp_of(i, m, n_eff):
    if (i, m) not in _cache:
        _cache[(i, m)] = refine_loop_icp(lcs[(i, m)], encs[i], encs[m], dataclasses.replace(LoopConfig(), icp_effective_points=1.0))
    r = _cache[(i, m)]
    return None if r is None else dataclasses.replace(r, information=r.information * n_eff)

def loop_ids(sp):
    return key_of[int(sp[1][0])], key_of[int(sp[1][1])]

def variant(name):
    if name == "asis":
        return lambda sp: sp
    if name == "off":
        return lambda sp: None
    if name.startswith("sig="):
        s = float(name[4:]); return lambda sp: (sp[0], (*sp[1][:4], s), sp[2])
    if name == "rms":
        def m(sp):
            lc = lcs.get(loop_ids(sp)); return (sp[0], (*sp[1][:4], max(inlier_rms(lc), 0.25 * lc.threshold)), sp[2])
        return m
    if name.startswith("icp"):
        kv = dict(p.split("=") for p in name.split(","))
        n_eff = float(kv.get("icp", kv.get("icpx"))); huber = float(kv.get("huber", 3.0))
        def m(sp):
            i, m_ = loop_ids(sp); r = icp_of(i, m_, n_eff)
            if r is None:
                return sp
            return ("relative_pose", (sp[1][0], sp[1][1], r.T_i_m, r.information, huber, "sim3"), {})
        return m
    raise SystemExit(f"unknown variant {name}")

def run(name):
    a, b, _ = rp.replay(st, variant(name), overrides=[], batch=True)
    return a, b

if __name__ == "__main__":
    rp_mode = "rgbd"
    orig = rp.load_config
    rp.load_config = lambda p, o, mode: orig(p, o, mode=rp_mode)
    for name in sys.argv[2:]:
        a, b = run(name)
        n_ok = sum(1 for k in lcs if name.startswith("icp") and _cache.get(k) is not None)
        print(f"{name:28s} kf ATE online {a:.3f} cm, after batch {b:.3f} cm  (icp ok {n_ok}/{len(lcs)})", flush=True)
