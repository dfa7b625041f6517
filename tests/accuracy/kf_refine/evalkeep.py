"""Measuring tool (docs/results.md, "Corrections inside submaps, session 7"): load a run kept by keep.py,
finish it (the final batch), keyframe and all-frame ATE (SE(3) RGB-D, Sim(3) mono); then the keyframe
refinement (``graph.keyframe_refine=true`` plus each ``"k=v;k=v"`` argument), the same ATEs again.
Prints one JSON line. Usage: ``PYTHONPATH=. python evalkeep.py OUT ["" "graph.keyframe_refine_rot_sigma=0.002;..."]``."""
import sys, json, time, logging
from pathlib import Path
import numpy as np
sys.path.insert(0, str(Path(__file__).parent))
from keep import open_seq
from gsslam.config import load_config
from gsslam.slam.pipeline import Pipeline
from gsslam.run.checkpoint import load_checkpoint
from gsslam.slam.keyframe_refine import refine_chains
from gsslam.eval.ate import compute_ate
from gsslam.types import Trajectory

def ate(gt, ts, P, align):
    ks = sorted(P)
    tr = Trajectory(np.array([ts[k] for k in ks]), np.stack([P[k] for k in ks]))
    r, _ = compute_ate(gt, tr, align=align)
    return 100 * r.stats.rmse

run = Path(sys.argv[1]); sets = sys.argv[2:]
meta = json.load(open(run / "keep.json"))
logging.basicConfig(level=logging.WARNING)
logging.getLogger("gsslam.slam.keyframe_refine").setLevel(logging.INFO)
ds = open_seq(meta["name"], meta["mode"], run)
ov = ["mapper.enabled=false", f"loop.enabled={'true' if meta['loops'] == 'on' else 'false'}", *meta.get("extra", [])]
cfg = load_config(None, ov, mode=meta["mode"])
pipe, _ = load_checkpoint(run, Pipeline(cfg, ds.intrinsics), {"config_sha256": "kfr", "dataset": {"name": meta["name"], "mode": meta["mode"]}})
gt = ds.ground_truth(); ts = pipe.timestamps
align = "sim3" if meta["mode"] == "mono" else "se3"
t0 = time.perf_counter(); pipe.finish(); tb = time.perf_counter() - t0
kb, fb = pipe.keyframe_poses(), pipe.frame_poses()
row = dict(run=run.name, kf=len(kb), frames=len(fb), kf_before=ate(gt, ts, kb, align), all_before=ate(gt, ts, fb, align), batch_s=tb)
for s in sets or [""]:
    c2 = load_config(None, ov + ["graph.keyframe_refine=true"] + ([x for x in s.split(";") if x]), mode=meta["mode"])
    for ch in pipe.chains: ch.refined_poses = None
    t0 = time.perf_counter(); ev = refine_chains(pipe.chains, c2.graph, pipe.monocular); tr = time.perf_counter() - t0
    ka, fa = pipe.keyframe_poses(), pipe.frame_poses()
    row[s or "default"] = dict(kf_after=ate(gt, ts, ka, align), all_after=ate(gt, ts, fa, align), refine_s=tr, events=[e.detail for e in ev])
print(json.dumps(row))
