"""Loop diagnostics against ground truth on the ray-cast Kinect room prefix (session 15, docs/results.md "RGB-D loops that correct, session 15"): per loop, the RANSAC (and ICP) relative pose, the estimate before / after the loop, before / after the final batch vs the truth; whitened chi2 per factor class at the estimate and at the truth.

    PYTHONPATH=. python3 tests/accuracy/loop_truth_s15.py OUT N_FRAMES [key=value ...]   (PAIRS=1: also every keyframe pair's ICP; SEQ=loop800: synth_loop800)

Not a test: a measuring tool (monkeypatches the pipeline to record; scratch quality)."""
import json, sys, pickle, logging
from pathlib import Path
import numpy as np, yaml
import gtsam
from gsslam.config import load_config
from gsslam.slam import pipeline as pl
from gsslam.slam import loop_stage as ls
from gsslam.run.sequence import run_sequence
from gsslam.factors import to_gtsam
from gsslam.graph.keys import submap_key

out = Path(sys.argv[1]); nfr = int(sys.argv[2]); overrides = sys.argv[3:]
out.mkdir(parents=True, exist_ok=True)
import os
if os.environ.get("SEQ") == "loop800":  # synth_loop800 (RGB-D row of the tracking suite)
    kw = dict(n_frames=800, width=320, height=240, trajectory="loop", seed=5)
else:  # the ray-cast Kinect room (tests/accuracy/room1000_raycast_s14.yaml)
  kw = dict(n_frames=1000, width=320, height=240, scene="furnished_room", trajectory="room_walk", seed=0,
            sensor="kinect_v1", misregister=dict(baseline_m=0.025, focal_scale=1.114, report="depth", raycast=True),
            degrade=dict(shutter=0.5, exposure_amp=0.25, exposure_period=150))
(out / "synthetic.yaml").write_text(yaml.safe_dump(kw))
cfg = load_config(None, ["mapper.enabled=false"] + overrides, mode="rgbd")
CAP = {}
orig_finish = pl.Pipeline.finish
def finish(self, *a, **k):
    CAP["pipe"] = self
    g = self.chains[0].graph
    CAP["before_batch"] = {i: g.submap_pose(i) for i in range(g.num_submaps)}
    return orig_finish(self, *a, **k)
pl.Pipeline.finish = finish
orig_after = ls.LoopStage.after_submap
def kabsch(A, B):  # T with A ~ T B
    ca, cb = A.mean(0), B.mean(0)
    U, _, Vt = np.linalg.svd((B - cb).T @ (A - ca))
    D = np.diag([1, 1, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    T = np.eye(4); T[:3, :3] = R; T[:3, 3] = ca - R @ cb
    return T
LOOPLOG = []
def after(self, chain, cid, sid, enc, frames):
    g = chain.graph
    before = set(self._loops.get(cid, {}).keys())
    pre = {k: g.submap_pose(k) for k in range(g.num_submaps)}
    r = orig_after(self, chain, cid, sid, enc, frames)
    post = {k: g.submap_pose(k) for k in range(g.num_submaps)}
    for h, lc in self._loops.get(cid, {}).items():
        if h not in before:
            LOOPLOG.append(dict(h=h, i=lc.i, m=lc.m, T=lc.T_i_m, K=kabsch(lc.X_i, lc.X_m), n=len(lc), pre=np.linalg.inv(pre[lc.i]) @ pre[lc.m],
                                post=np.linalg.inv(post[lc.i]) @ post[lc.m]))
    return r
ls.LoopStage.after_submap = after
ICP = {}
orig_ref = ls.LoopStage._refine_icp
def refine(self, chain, lc):
    r = orig_ref(self, chain, lc)
    if r is not None: ICP[(lc.i, lc.m)] = r
    return r
ls.LoopStage._refine_icp = refine
run_sequence(out / "synthetic.yaml", "synthetic", cfg, out / "run", max_frames=nfr, progress=False, overwrite=True, **{})
pipe = CAP["pipe"]; g = pipe.chains[0].graph
from gsslam.datasets import open_dataset
gt = open_dataset("synthetic", out / "synthetic.yaml").ground_truth().poses
def rel(A, B):
    D = np.linalg.inv(A) @ B
    s = np.cbrt(np.linalg.det(D[:3, :3])); R = D[:3, :3] / s
    ang = np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)))
    return np.linalg.norm(D[:3, 3]) * 1e3, ang
subs = g._subs
f0 = [int(e.frame_indices[0]) for e in subs]
G = {i: np.linalg.inv(gt[f0[0]]) @ gt[f0[i]] for i in range(len(subs))}
final = {i: g.submap_pose(i) for i in range(len(subs))}
bb = CAP["before_batch"]
rows = []
for L in LOOPLOG:
    i, m = L["i"], L["m"]
    Tgt = np.linalg.inv(G[i]) @ G[m]
    def err(T): return rel(Tgt, T)
    rows.append(dict(i=i, m=m, n=L["n"], meas=err(L["T"]), kab=err(L["K"]), pre=err(L["pre"]), post=err(L["post"]),
                     bb=err(np.linalg.inv(bb[i]) @ bb[m]), final=err(np.linalg.inv(final[i]) @ final[m]),
                     icp=err(ICP[(i, m)].T_i_m) if (i, m) in ICP else (np.nan, np.nan)))
from gsslam.loop.icp_loop import icp_point_to_plane, LOOP_ICP_STRIDES, ICP_MAX_SHIFT_DEG
from gsslam.geometry import so3_log
def pair_icps(L):
    encs = pipe.chains[0].encodings; ei, em = encs[L["i"]], encs[L["m"]]
    same = np.asarray(ei.frame_indices)[:, None] == np.asarray(em.frame_indices)[None, :]
    zi = ei.depths; dm = float(np.nanmedian(zi))
    C_m = L["T"][None] @ em.T_local_cam
    out = []
    for v in range(len(ei.frame_indices)):
        A = ei.T_local_cam[v]
        dt = np.linalg.norm(A[None, :3, 3] - C_m[:, :3, 3], axis=-1)
        Rr = np.einsum("ji,ujk->uik", A[:3, :3], C_m[:, :3, :3])
        cost = dt + np.arccos(np.clip((np.trace(Rr, axis1=1, axis2=2) - 1) / 2, -1, 1)) * dm
        cost = np.where(same[v], np.inf, cost); u = int(np.argmin(cost))
        if not np.isfinite(cost[u]): continue
        B = em.T_local_cam[u]
        T0 = np.linalg.inv(A) @ L["T"] @ B
        res = icp_point_to_plane(em.depths[u], ei.depths[v], ei.intrinsics, T0, strides=LOOP_ICP_STRIDES,
                                 max_step_m=cfg.loop.icp_max_shift_m, max_step_deg=ICP_MAX_SHIFT_DEG)
        if res.ok and res.hessian is not None:
            out.append((v, u, float(cost[u]), A @ res.T_tgt_src @ np.linalg.inv(B)))
    return out
def mean_T(Ts):
    R = sum(T[:3, :3] for T in Ts); U, _, Vt = np.linalg.svd(R); R = U @ np.diag([1, 1, np.linalg.det(U @ Vt)]) @ Vt
    T = np.eye(4); T[:3, :3] = R; T[:3, 3] = np.mean([T_[:3, 3] for T_ in Ts], 0); return T
print("per-pair ICP: loop | closest pair | median pair | mean of pairs | mean of 3 closest  (mm deg)  npairs")
PP = []; import os; DOPAIRS = os.environ.get("PAIRS", "0") == "1"
for L in (LOOPLOG if DOPAIRS else []):
  try:
    Tgt = np.linalg.inv(G[L["i"]]) @ G[L["m"]]
    pr = pair_icps(L)
    if not pr: continue
    pr.sort(key=lambda x: x[2])
    e = [rel(Tgt, p[3]) for p in pr]
    c3 = rel(Tgt, mean_T([p[3] for p in pr[:3]])); ma = rel(Tgt, mean_T([p[3] for p in pr]))
    med = (float(np.median([x[0] for x in e])), float(np.median([x[1] for x in e])))
    PP.append((e[0][0], med[0], ma[0], c3[0]))
    print(f"{L['i']:3d}-{L['m']:3d} | {e[0][0]:6.2f} {e[0][1]:5.2f} | {med[0]:6.2f} {med[1]:5.2f} | {ma[0]:6.2f} {ma[1]:5.2f} | {c3[0]:6.2f} {c3[1]:5.2f} | {len(pr)}")
  except Exception as ex: print("pair icp failed", ex)
if PP: print("median closest/median/meanall/mean3", np.round(np.median(np.array(PP), 0), 2))
print("loop  n   | meas-gt mm/deg | kabsch-gt | icp-gt | pre-gt | post-gt | beforebatch-gt | final-gt")
for r in rows:
    print(f"{r['i']:3d}-{r['m']:3d} {r['n']:4d} | " + " | ".join(f"{r[k][0]:6.2f} {r[k][1]:5.2f}" for k in ("meas", "kab", "icp", "pre", "post", "bb", "final")))
a = np.array([[r[k][0] for k in ("meas", "kab", "icp", "pre", "post", "bb", "final")] for r in rows])
if len(a): print("median mm meas/kab/icp/pre/post/bb/final", np.round(np.nanmedian(a, 0), 2), "mean", np.round(np.nanmean(a, 0), 2))
# chi2 per factor class at the estimate and at the truth
be = g.backend
loop_h = set(pipe.loop_stage._loops.get(0, {}).keys())
vals = be.values()
tv = gtsam.Values(vals)
for i in range(len(subs)):
    tv.update(submap_key(i), to_gtsam(G[i], "sim3"))
cls = {}
for h, f in be._factors.items():
    kind = be._specs[h][0] if h in be._specs else "?"
    if h in loop_h: kind = "LOOP_" + kind
    elif kind == "relative_pose": kind = "icp_neighbour"
    elif kind == "point": kind = "adjacency"
    d = f.dim()
    e1, e2 = 2 * f.error(vals), 2 * f.error(tv)
    c = cls.setdefault(kind, [0, 0, 0.0, 0.0]); c[0] += 1; c[1] += d; c[2] += e1; c[3] += e2
print("class          n   dim   chi2@est  chi2@truth  (chi2/dim est, truth)")
for k, (n, d, e1, e2) in sorted(cls.items()):
    print(f"{k:22s} {n:4d} {d:6d} {e1:10.2f} {e2:10.2f}  {e1/d:7.3f} {e2/d:7.3f}")
m = json.loads((out / "run" / "metrics.json").read_text())
print("ATE cm", round(m["ate"]["rmse_m"] * 100, 3), "before batch", round(m["ate_before_batch"]["rmse_m"] * 100, 3),
      "loops", {k: m["loop_closure"][k] for k in ("detected", "accepted", "in_graph")})
pickle.dump(dict(rows=rows, cls=cls), open(out / "diag.pkl", "wb"))
