"""Replay an RGB-D run kept by ``exp.py --keep-depth`` with its loop factors replaced (docs/results.md,
"RGB-D loops with ICP, session 6"): as is, no loops, point sigma from the loop's inlier RMS, or the
ICP relative-pose factor (gsslam.loop.icp_loop) at several effective point counts.
Usage: ``PYTHONPATH=. python icp_rexp.py PKL [variant ...]``; variants: asis off rms sig=S icp=N_EFF
icp=N_EFF,huber=H icpx=N_EFF (ICP factor added next to the point factor)."""
import dataclasses, pickle, sys
sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))  # replay.py
import replay as rp
from gsslam.config import LoopConfig, load_config
from gsslam.loop.icp_loop import refine_loop_icp
from gsslam.loop.types import LoopConstraint
from gsslam.loop.weights import inlier_rms

st = pickle.load(open(sys.argv[1], "rb"))
encs, key_of = rp.kept_encodings(st)
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
        both = name.startswith("icpx")
        def m(sp):
            i, m_ = loop_ids(sp); r = icp_of(i, m_, n_eff)
            if r is None:
                return sp
            new = ("relative_pose", (sp[1][0], sp[1][1], r.T_i_m, r.information, huber, "sim3"), {})
            return [sp, new] if both else new
        return m
    raise SystemExit(f"unknown variant {name}")

def run(name):
    """rp.replay, but a loop may become several factors (handles renumbered; no loop was removed)."""
    from gsslam.graph.backend import Backend
    from gsslam.graph.factor_specs import build_factor
    from gsslam.factors import to_gtsam
    assert not any(op[0] == "remove" for op in st["replay"])
    be = Backend.from_config(load_config(None, ["mapper.enabled=false"], mode="rgbd").graph)
    vmap = variant(name)
    for op in st["replay"]:
        if op[0] == "factor":
            sps = vmap(op[2]) if rp.is_loop(op[2]) else op[2]
            if sps is None:
                k, a, kw = op[2]; sps = (k, (*a[:4], 1e6), kw)
            for sp in (sps if isinstance(sps, list) else [sps]):
                be.add_factor(build_factor(sp), None, spec=sp)
        elif op[0] == "value":
            be.add_value(int(op[1]), to_gtsam(op[2], "sim3"))
        elif op[0] == "update":
            be.update(int(op[1]))
    a = rp.ate(st, rp.kf_poses(be.values(), st))
    be.refine_batch()
    return a, rp.ate(st, rp.kf_poses(be.values(), st))

if __name__ == "__main__":
    for name in sys.argv[2:]:
        a, b = run(name)
        n_ok = sum(1 for k in lcs if name.startswith("icp") and _cache.get(k) is not None)
        print(f"{name:28s} kf ATE online {a:.3f} cm, after batch {b:.3f} cm  (icp ok {n_ok}/{len(lcs)})", flush=True)
