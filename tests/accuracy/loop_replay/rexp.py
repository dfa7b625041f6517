"""Replay a run kept by exp.py with its loop factors changed (docs/results.md, "Mono loops, session 5")."""
import pickle, sys, numpy as np
sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))  # replay.py
from replay import replay, is_loop
from gsslam.geometry import invert_T, transform_points
st = pickle.load(open(sys.argv[1], "rb"))
gt, ts = st["gt"], st["ts"]
def gt_at(t):
    i = np.clip(np.searchsorted(gt.timestamps, t), 0, len(gt.timestamps)-1); return gt.poses[i]
mpl = []
for fi, L in zip(st["frame_indices"], st["T_local_cam"]):
    G = np.stack([gt_at(ts[f]) for f in fi]); Grel = np.array([invert_T(G[0]) @ g for g in G])
    mpl.append(np.linalg.norm(Grel[:, :3, 3], axis=1).sum() / np.linalg.norm(L[:, :3, 3], axis=1).sum())
def G_of(k):
    g = gt_at(ts[st["frame_indices"][k][0]]).copy(); g[:3, :3] *= mpl[k]; return g
def gt_loop(sp):
    k, a, kw = sp
    from gsslam.graph.keys import submap_key
    i = [j for j in range(len(mpl)) if submap_key(j) == a[0]][0]; m = [j for j in range(len(mpl)) if submap_key(j) == a[1]][0]
    Tim = invert_T(G_of(i)) @ G_of(m)
    return (k, (a[0], a[1], transform_points(Tim, a[3]), a[3], a[4]), kw)
def sig(s):
    return lambda sp: (sp[0], (*sp[1][:4], s), sp[2])
def flow(f):
    def m(sp):
        if sp[0] != "flow": return sp
        kw = dict(sp[2]); kw["weight"] = kw["weight"] * f; return (sp[0], sp[1], kw)
    return m
def thr_sig(f):
    # per-point sigma = f * the loop's inlier threshold (local-i units) in world units
    def m(sp):
        lc = [l for l in st["loopc"] if l["X_m"].shape == sp[1][3].shape and np.allclose(l["X_m"], sp[1][3])][0]
        from gsslam.graph.keys import submap_key
        i = [j for j in range(len(mpl)) if submap_key(j) == sp[1][0]][0]
        s_i = np.cbrt(np.linalg.det(st["S_before"][i][:3, :3]))
        return (sp[0], (*sp[1][:4], f * lc["thr"] * s_i), sp[2])
    return m
def rms_sig(sp):
    from gsslam.geometry import umeyama
    Xi, Xm = sp[1][2], sp[1][3]; T = umeyama(Xm, Xi, with_scale=True)
    r = np.sqrt(np.mean(np.sum((transform_points(T, Xm) - Xi)**2, 1)))
    lc = dict(thr=r)
    from gsslam.graph.keys import submap_key
    i = [j for j in range(len(mpl)) if submap_key(j) == sp[1][0]][0]
    s_i = np.cbrt(np.linalg.det(st["S_before"][i][:3, :3]))
    print("rms sigma", r * s_i)
    return (sp[0], (*sp[1][:4], r * s_i), sp[2])
def rel_rms(sp):
    from gsslam.geometry import umeyama
    Xi, Xm = sp[1][2], sp[1][3]; T = umeyama(Xm, Xi, with_scale=True)
    r = np.sqrt(np.mean(np.sum((transform_points(T, Xm) - Xi)**2, 1)))
    return ("relative_point", (sp[1][0], sp[1][1], Xi, Xm, r), {})
exps = {"relrms": dict(loop_map=rel_rms), "thr1": dict(loop_map=thr_sig(1.0)), "thr0.5": dict(loop_map=thr_sig(0.5)), "rms": dict(loop_map=rms_sig), "sig0.02": dict(loop_map=sig(0.02)), "sig0.005": dict(loop_map=sig(0.005)), "flow0.1": dict(other_map=flow(0.1)), "gtloop_flow0.1": dict(loop_map=gt_loop, other_map=flow(0.1)), "off_flow0.1": dict(loop_map=lambda sp: None, other_map=flow(0.1)),"asis": dict(), "off": dict(loop_map=lambda sp: None), "gtloop": dict(loop_map=gt_loop),
        "sig0.01": dict(loop_map=sig(0.01)), "gtloop_sig0.01": dict(loop_map=lambda sp: sig(0.01)(gt_loop(sp)))}
for name in sys.argv[2:]:
    a, b, _ = replay(st, **exps[name])
    print(f"{name}: kf ATE before batch {a:.3f} after batch {b:.3f}", flush=True)
