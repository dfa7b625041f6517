"""Per-keyframe scale and accuracy of the RGB-D encoder (PnP vs ICP) on teddy, registered or misregistered.

    PYTHONPATH=. python tests/accuracy/encoder_scale.py [plain|misreg_corr|misreg_true|misreg_nobase|...]

Submaps of 7 keyframes 3 frames apart over the first 180 frames; for each case prints the
translation-norm ratio est / gt (least squares), mean translation and rotation errors of the local poses.
Misregistered cases are registered by ``depth_registration.register_frame``: session 4's focal ratio
alone (estimated 1.108 or true 1.114, no baseline) or session 5's full registration (ratio + baseline,
estimated or true; ``*_full``), with the depth camera's (7-Scenes) or the colour camera's intrinsics given.
Not a test: a measuring tool (docs/results.md, "Accuracy at length, session 4").
"""
import numpy as np, sys
from dataclasses import replace
from gsslam.config import load_config
from gsslam.datasets.base import open_dataset
from gsslam.frontend.flow import make_flow_estimator
from gsslam.frontend.encoder import make_encoder
from gsslam.frontend.depth_registration import DepthRegistration, register_frame
from gsslam.geometry import invert_T, so3_log
cfg = load_config(None, [], mode="rgbd")
MIS = {"baseline_m": 0.025, "focal_scale": 1.114}
F = dict(base="tum", pattern="f")
cases = {
 "plain": (F, None),
 "misreg_corr": ({**F, "misregister": {**MIS, "report": "depth"}}, DepthRegistration(1.108)),
 "misreg_true": ({**F, "misregister": {**MIS, "report": "depth"}}, DepthRegistration(1.114)),
 "misreg_nobase": ({**F, "misregister": {**MIS, "baseline_m": 0.0, "report": "depth"}}, DepthRegistration(1.114)),
 "depth_full": ({**F, "misregister": {**MIS, "report": "depth"}}, DepthRegistration(1.1259, 0.0259, "depth")),
 "depth_full_true": ({**F, "misregister": {**MIS, "report": "depth"}}, DepthRegistration(1.114, 0.025, "depth")),
 "colour_s4": ({**F, "misregister": MIS}, DepthRegistration(1.076)),  # session 4 on colour intrinsics
 "colour_full": ({**F, "misregister": MIS}, DepthRegistration(1.1078, 0.0264, "colour")),
}
which = sys.argv[1:] or list(cases)
for name in which:
    kw, reg = cases[name]
    ds = open_dataset("playback", "../shared/data/rgbd_dataset_freiburg3_teddy", **kw)
    for icp in (False, True):
        enc = make_encoder("rgbd", replace(cfg.encoder, rgbd_icp=icp, rgbd_icp_auto=False), make_flow_estimator(cfg.flow))
        num = den = 0.0; rerr = []; terr = []
        for s in range(0, 180, 21):
            idx = list(range(s, s + 21, 3))
            fr = [ds[i] for i in idx]
            if any(f.depth is None or f.T_world_cam_gt is None for f in fr): continue
            fr = [register_frame(f, reg) for f in fr] if reg is not None else fr
            e = enc.encode(fr)
            G0 = fr[0].T_world_cam_gt
            for j in range(1, len(fr)):
                Tg = invert_T(G0) @ fr[j].T_world_cam_gt
                Te = e.T_local_cam[j]
                num += np.linalg.norm(Te[:3, 3]) * np.linalg.norm(Tg[:3, 3]); den += np.linalg.norm(Tg[:3, 3])**2
                terr.append(np.linalg.norm(Te[:3, 3] - Tg[:3, 3]))
                rerr.append(np.degrees(np.linalg.norm(so3_log(Te[:3,:3].T @ Tg[:3,:3]))))
        print(name, "icp" if icp else "pnp", f"trans-norm ratio est/gt {num/den:.4f}  terr {100*np.mean(terr):.2f} cm  rerr {np.mean(rerr):.2f} deg", flush=True)
