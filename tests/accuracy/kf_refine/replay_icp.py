"""Measuring tool (docs/results.md, "Corrections inside submaps, session 7"): a run kept by
``loop_replay/exp.py --keep-depth`` replayed with ICP loops (n_eff 100, as icp_rexp.py), then the keyframe
refinement at each tie sigma "ROT,TRANS"; keyframe ATE (Sim(3)). Usage:
``PYTHONPATH=. python replay_icp.py PKL 0.001,0.001 ...``."""
import sys, numpy as np
from pathlib import Path
sys.path.insert(0, str(Path(__file__).parents[1] / "loop_replay"))
import icp_rexp as ir   # loads sys.argv[1]
import replay as rp
from gsslam.graph.keys import submap_key
from gsslam.factors import to_matrix
from gsslam.slam.keyframe_refine import refine_keyframes, RefineSettings
st = ir.st
lm = ir.variant("icp=100")
a, b, be = rp.replay(st, loop_map=lm)
print("submap-level ICP loops: kf ATE before batch %.3f after %.3f" % (a, b))
vals = be.values()
S = [to_matrix(vals.atSimilarity3(submap_key(k))) for k in range(len(st["frame_indices"]))]
specs = be.live_specs()
for arg in sys.argv[2:]:
    rs, ts_ = map(float, arg.split(","))
    r = refine_keyframes(st["frame_indices"], st["T_local_cam"], S, specs, RefineSettings(rs, ts_),
                         depths=list(st["enc_depth"]), Ks=[i.K for i in st["enc_intr"]])
    print("tie %s: kf ATE %.3f moved %s" % (arg, rp.ate(st, r.poses), r.moved))
