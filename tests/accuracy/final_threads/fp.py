"""The final pass alone on a pickled MapState: threads N, wall + CPU; optional PSNR at 160 / 640 px.

python3 fp.py SNAP.pkl DATASET TORCH_THREADS,COMPOSITOR_THREADS TAG [eval]   (writes params_TAG.npz here)
"""

import dataclasses
import json
import logging
import os
import pickle
import sys
import time

import numpy as np
import torch

from gsslam.datasets.base import open_dataset
from gsslam.mapping import final_pass, outputs
from gsslam.mapping.keyframes import torch_threads
from gsslam.mapping.state import refined_poses

snap, dpath, spec, tag = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4]
torch_t, threads = (int(x) for x in spec.split(","))
do_eval = len(sys.argv) > 5 and sys.argv[5] == "eval"
logging.basicConfig(level=logging.WARNING)
torch.set_num_threads(1)
with open(snap, "rb") as f:
    state = pickle.load(f)
over = {"num_threads": torch_t}
if hasattr(state.cfg, "final_num_threads"):
    over["final_num_threads"] = threads
state.cfg = dataclasses.replace(state.cfg, **over)
load0 = os.getloadavg()[0]
t0, c0, m0 = time.perf_counter(), time.process_time(), time.thread_time()
st = final_pass.finalize(state)
wall, cpu, main = time.perf_counter() - t0, time.process_time() - c0, time.thread_time() - m0
row = {
    "tag": tag,
    "torch_threads": torch_t,
    "compositor_threads": threads,
    "wall_s": round(wall, 2),
    "cpu_s": round(cpu, 2),
    "main_thread_cpu_s": round(main, 2),
    "iters": st["iterations"],
    "gaussians": len(state.model),
    "load": [round(load0, 1), round(os.getloadavg()[0], 1)],
    "step_psnr_last": st.get("last_psnr", st.get("psnr_last")),
}
p = {k: v.detach().numpy() for k, v in state.model.params().items()}
np.savez(f"params_{tag}.npz", **p)
if do_eval:
    ds = open_dataset("tum", dpath)
    poses = refined_poses(state)
    torch.set_num_threads(1)
    with torch_threads(1):
        ev = outputs.evaluate_map(state, (ds[i] for i in range(len(ds))), poses, ds.intrinsics)
    row.update(
        {
            k: ev.get(k)
            for k in ("psnr_keyframes", "psnr_keyframes_native", "ssim_keyframes", "ssim_keyframes_native")
        }
    )
print(json.dumps(row), flush=True)
