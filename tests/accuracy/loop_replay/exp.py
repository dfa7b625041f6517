"""Measuring tool (docs/results.md, "Mono loops, session 5"), not a test: run a sequence in-process with
the map off, keep the graph's replay log, the loops and the poses before/after the batch in
``$LOOP_REPLAY_OUT/<seq>_<mode>_<loops>_<tag>.pkl`` (default /tmp/loop_replay); replay it with
``rexp.py PKL asis off gtloop rms relrms ...``. Usage: ``PYTHONPATH=. python exp.py synth800 --loops on --tag rep``."""
import os
import argparse, json, logging, pickle, sys, time
from pathlib import Path
import numpy as np, yaml
from gsslam.config import load_config
from gsslam.datasets.base import open_dataset
from gsslam.slam.pipeline import Pipeline
from gsslam.eval.ate import compute_ate
from gsslam.types import Trajectory

OUT = os.environ.get("LOOP_REPLAY_OUT", "/tmp/loop_replay")
DATA = os.environ.get("GSSLAM_DATA", "../shared/data")  # the data root
os.makedirs(OUT, exist_ok=True)
SEQ = {
    "synth800": ("synthetic", str(Path(__file__).with_name("synth800.yaml")), {}),
    "fbf": ("playback", DATA + "/rgbd_dataset_freiburg3_teddy",
            dict(base="tum", pattern="fbf", pause_every=97, pause_len=15, jump_every=151, jump_len=4, seed=0)),
    # the tracking suite's teddy200_fbf mono row: the playback opened as the runner opens it (with depth: 640 frames)
    "fbfs": ("playback", DATA + "/rgbd_dataset_freiburg3_teddy",
             dict(base="tum", pattern="fbf", pause_every=97, pause_len=15, jump_every=151, jump_len=4, seed=0)),
    "fbf_misreg": ("playback", DATA + "/rgbd_dataset_freiburg3_teddy",
            dict(base="tum", pattern="fbf", pause_every=97, pause_len=15, jump_every=151, jump_len=4, seed=0,
                 misregister=dict(baseline_m=0.025, focal_scale=1.114))),
    "teddy200": ("tum", DATA + "/rgbd_dataset_freiburg3_teddy", {}),
    # the tracking suite's 7-Scenes proxies (session 9): the rows above handed out with depth intrinsics
    "fbf_7scenes": ("playback", DATA + "/rgbd_dataset_freiburg3_teddy",
            dict(base="tum", pattern="fbf", pause_every=97, pause_len=15, jump_every=151, jump_len=4, seed=0,
                 misregister=dict(baseline_m=0.025, focal_scale=1.114, report="depth"))),
    "s2blur_7scenes": ("playback", DATA + "/rgbd_dataset_freiburg3_teddy",
               dict(base="tum", pattern="fbfbf", stride=2,
                    degrade=dict(shutter=0.5, exposure_amp=0.25, exposure_period=150),
                    misregister=dict(baseline_m=0.025, focal_scale=1.114, report="depth"))),
    # the tracking suite's teddy200_s2_blur_7scenes_mono row with the handed-out focal scaled by --focal
    # (session 11 sweep; opened as the runner opens a playback row; run it with --max-frames 300)
    "s2blur_f": ("playback", DATA + "/rgbd_dataset_freiburg3_teddy",
                 dict(base="tum", pattern="fbfbf", stride=2,
                      degrade=dict(shutter=0.5, exposure_amp=0.25, exposure_period=150))),
    # the tracking suite's teddy200_s2_blur row (run it with --max-frames 300)
    "s2blur": ("playback", DATA + "/rgbd_dataset_freiburg3_teddy",
               dict(base="tum", pattern="fbfbf", stride=2,
                    degrade=dict(shutter=0.5, exposure_amp=0.25, exposure_period=150))),
}

def traj(ts, poses, keys):
    keys = [k for k in keys if k in poses]
    return Trajectory(np.array([ts[k] for k in keys]), np.stack([poses[k] for k in keys]))

def ate(gt, ts, poses):
    res, _ = compute_ate(gt, traj(ts, poses, sorted(poses)), align="sim3")
    return 100 * res.stats.rmse, float(res.alignment.scale)

def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("seq"); ap.add_argument("--mode", default="mono"); ap.add_argument("--loops", default="on")
    ap.add_argument("--set", action="append", default=[]); ap.add_argument("--tag", default="")
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--focal", type=float, default=None,
                    help="s2blur_f: the focal scale handed out (misregister report=depth; mono reads no depth)")
    ap.add_argument("--keep-depth", action="store_true", help="also keep every submap's depth maps (ICP replay)")
    a = ap.parse_args()
    logging.basicConfig(level=logging.INFO if 0 else logging.WARNING)
    logging.getLogger("gsslam.loop").setLevel(logging.INFO); logging.getLogger("gsslam.slam.loop_stage").setLevel(logging.INFO)
    dsname, path, kw = SEQ[a.seq]
    kw = dict(kw)
    if a.seq == "s2blur_f":
        kw["misregister"] = dict(baseline_m=0.025, focal_scale=a.focal, report="depth")
    if a.mode == "mono" and dsname in ("tum", "playback") and a.seq not in ("fbfs", "s2blur_f"):
        kw.setdefault("with_depth", False)
    ds = open_dataset(dsname, path, **kw)
    cfg = load_config(None, ["mapper.enabled=false", f"loop.enabled={'true' if a.loops=='on' else 'false'}", *a.set], mode=a.mode)
    from dataclasses import replace
    from gsslam.frontend.depth_registration import register_frame
    from gsslam.run.sequence import colour_registration
    reg, _ = colour_registration(ds, cfg, a.max_frames)  # as the runner does (run/sequence.py)
    if reg.is_identity():
        reg = None
    else:
        cfg = replace(cfg, encoder=replace(cfg.encoder, rgbd_icp=True))
    pipe = Pipeline(cfg, ds.intrinsics if reg is None else reg.colour_intrinsics(ds.intrinsics))
    n = len(ds) if a.max_frames is None else min(len(ds), a.max_frames)
    t0 = time.time()
    for i in range(n):
        pipe.process(ds[i] if reg is None else register_frame(ds[i], reg))
    pipe.close_chain()
    gt = ds.ground_truth()
    ts = pipe.timestamps
    state = {"kf_before": pipe.keyframe_poses(), "fr_before": pipe.frame_poses()}
    ch = pipe.chains[0]
    state["S_before"] = [ch.graph.submap_pose(k) for k in range(ch.graph.num_submaps)]
    from gsslam.factors import to_matrix
    state["replay"] = [(op[0], op[1], to_matrix(op[2])) if op[0] == "value" else op for op in ch.graph.backend.replay_log()]
    pipe.finish()
    state["kf_after"] = pipe.keyframe_poses(); state["fr_after"] = pipe.frame_poses()
    state["S_after"] = [ch.graph.submap_pose(k) for k in range(ch.graph.num_submaps)]
    state["T_local_cam"] = [e.T_local_cam for e in ch.encodings]
    state["frame_indices"] = [list(e.frame_indices) for e in ch.encodings]
    state["ts"] = ts; state["gt"] = gt; state["loops"] = pipe.loop_stage.metrics()
    state["chains"] = len(pipe.chains)
    state["loopc"] = [dict(i=lc.i, m=lc.m, X_i=lc.X_i, X_m=lc.X_m, T_i_m=lc.T_i_m, thr=lc.threshold,
                           view_i=lc.view_i, view_m=lc.view_m) for d in pipe.loop_stage._loops.values() for lc in d.values()]
    if a.keep_depth:
        state["enc_depth"] = [e.points_cam[..., 2].astype(np.float32) for e in ch.encodings]
        state["enc_intr"] = [e.intrinsics for e in ch.encodings]
    state["enc_depth_med"] = [float(np.nanmedian(e.points_cam[..., 2])) for e in ch.encodings]
    row = dict(seq=a.seq, focal=a.focal, mode=a.mode, loops=a.loops, set=a.set, tag=a.tag, chains=len(pipe.chains),
               submaps=ch.graph.num_submaps,
               ate_all=ate(gt, ts, state["fr_after"]), ate_kf=ate(gt, ts, state["kf_after"]),
               ate_before=ate(gt, ts, state["fr_before"]), ate_kf_before=ate(gt, ts, state["kf_before"]),
               lc={k: state["loops"][k] for k in ("candidates", "detected", "accepted", "rejected", "in_graph")},
               wall=time.time() - t0)
    print(json.dumps(row))
    with open(f"{OUT}/results.jsonl", "a") as f:
        f.write(json.dumps(row) + "\n")
    seq = a.seq if a.focal is None else f"{a.seq}{a.focal:g}"
    name = f"{OUT}/{seq}_{a.mode}_{a.loops}{('_' + a.tag) if a.tag else ''}.pkl"
    with open(name, "wb") as f:
        pickle.dump(state, f)

main()
