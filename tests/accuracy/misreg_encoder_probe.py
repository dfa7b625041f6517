"""Local (submap) pose accuracy of the RGB-D encoder on the blurred 2x teddy, registered or 7-Scenes-like.

    PYTHONPATH=. python tests/accuracy/misreg_encoder_probe.py CASE [CASE ...] [--frames 160]

Submaps of 7 keyframes 2 playback frames apart (about the keyframe spacing of ``teddy200_s2_blur``),
encoded at the default configuration (one encoder per case, so ``ColourDepthCheck`` accumulates as in
a run). Prints per case: translation-norm ratio est / gt, mean translation and rotation error of the
local poses, PnP/ICP rotation ratio, whether ICP poses were used, joint-posed keyframes.
Cases: ``reg`` (registered, colour intrinsics), ``reg_icp`` (same, ``rgbd_icp`` forced as the runner
does after a registration), ``7s_est`` (7-Scenes handout, the runner's estimate 1.1133 / 17.7 mm, ICP
forced), ``7s_true`` (true registration 1.114 / 25 mm, ICP forced), ``7s_true_noicp``, ``7s_est_noicp``.
Not a test: a measuring tool (docs/results.md, "Depth not registered to colour, session 9").
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from gsslam.config import load_config
from gsslam.datasets.base import open_dataset
from gsslam.frontend.depth_registration import DepthRegistration, register_frame
from gsslam.frontend.encoder import make_encoder
from gsslam.frontend.flow import make_flow_estimator
from gsslam.geometry import invert_T, so3_log

DEG = {"shutter": 0.5, "exposure_amp": 0.25, "exposure_period": 150}
BLUR = dict(base="tum", pattern="fbfbf", stride=2, degrade=DEG)
MIS = {"baseline_m": 0.025, "focal_scale": 1.114, "report": "depth"}
EST = DepthRegistration(1.1133, 0.0177, "depth", ok=True)
TRUE = DepthRegistration(1.114, 0.025, "depth", ok=True)
CASES = {  # name: (dataset kwargs, registration, force rgbd_icp)
    "reg": (BLUR, None, False),
    "reg_icp": (BLUR, None, True),
    "7s_est": ({**BLUR, "misregister": MIS}, EST, True),
    "7s_true": ({**BLUR, "misregister": MIS}, TRUE, True),
    "7s_est_noicp": ({**BLUR, "misregister": MIS}, EST, False),
    "7s_true_noicp": ({**BLUR, "misregister": MIS}, TRUE, False),
}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("cases", nargs="+")
    ap.add_argument("--frames", type=int, default=160)
    ap.add_argument("--set", action="append", default=[], dest="overrides")
    ap.add_argument("--reg", default=None, help="K,B override of the case's registration")
    a = ap.parse_args()
    cfg = load_config(None, a.overrides, mode="rgbd")
    for name in a.cases:
        kw, reg, force = CASES[name]
        if a.reg is not None and reg is not None:
            k, b = (float(x) for x in a.reg.split(","))
            reg = DepthRegistration(k, b, "depth", ok=True)
        ds = open_dataset("playback", "../shared/data/rgbd_dataset_freiburg3_teddy", **kw)
        enc = make_encoder("rgbd", replace(cfg.encoder, rgbd_icp=force or cfg.encoder.rgbd_icp),
                           make_flow_estimator(cfg.flow))  # fmt: skip
        num = den = 0.0
        terr, rerr, joint, use_icp, trace = [], [], 0, [], []
        for s in range(0, a.frames - 12, 12):
            fr = [ds[i] for i in range(s, s + 13, 2)]
            if any(f.depth is None or f.T_world_cam_gt is None for f in fr):
                continue
            fr = [register_frame(f, reg) for f in fr] if reg is not None else fr
            e = enc.encode(fr)
            joint += len(e.meta["joint_posed"])
            trace.append((enc.check.pairs, round(enc.check.ratio, 3), enc.check.mismatch))
            use_icp.append(bool(e.meta["use_icp"]))
            G0 = fr[0].T_world_cam_gt
            for j in range(1, len(fr)):
                Tg = invert_T(G0) @ fr[j].T_world_cam_gt
                Te = e.T_local_cam[j]
                num += np.linalg.norm(Te[:3, 3]) * np.linalg.norm(Tg[:3, 3])
                den += np.linalg.norm(Tg[:3, 3]) ** 2
                terr.append(np.linalg.norm(Te[:3, 3] - Tg[:3, 3]))
                rerr.append(np.degrees(np.linalg.norm(so3_log(Te[:3, :3].T @ Tg[:3, :3]))))
        print(f"{name} reg={reg and (reg.ratio, reg.baseline_m)}: scale {num / den:.4f} "
              f"terr {100 * np.mean(terr):.3f} cm rerr {np.mean(rerr):.3f} deg; "
              f"PnP/ICP rot ratio {enc.check.ratio:.3f}, use_icp {use_icp}, joint {joint}/{len(terr)}; "
              f"check (pairs, ratio, latched) per submap {trace}", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
