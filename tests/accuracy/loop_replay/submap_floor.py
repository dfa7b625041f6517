"""Measuring tool (docs/results.md, "RGB-D loops with ICP, session 6"): keyframe ATE with every submap at its
best rigid pose against ground truth (the floor of any submap-level correction). Usage:
``PYTHONPATH=. python submap_floor.py PKL`` with a run kept by exp.py."""
import pickle, sys, numpy as np
sys.path.insert(0, str(__import__('pathlib').Path(__file__).parent))
import replay as rp
from gsslam.geometry import umeyama, invert_T
st=pickle.load(open(sys.argv[1],'rb')); gt=st['gt']; ts=st['ts']
def gt_at(t):
    i=np.clip(np.searchsorted(gt.timestamps,t),0,len(gt.timestamps)-1); return gt.poses[i]
P={}
for fi,L in zip(st['frame_indices'],st['T_local_cam']):
    G=np.stack([gt_at(ts[f]) for f in fi])
    # best rigid S: minimise |S L_j c - G_j c| over camera centres + an axis point 0.5 m ahead (orientation)
    src=np.concatenate([L[:,:3,3], (L[:,:3,:3]@[0,0,0.5])+L[:,:3,3]]); dst=np.concatenate([G[:,:3,3], (G[:,:3,:3]@[0,0,0.5])+G[:,:3,3]])
    S=umeyama(src,dst,with_scale=False)
    for j,f in enumerate(fi):
        P.setdefault(f, S@L[j])
print("kf ATE with every submap at its best rigid pose (intra-submap floor): %.3f cm" % rp.ate(st,P))
