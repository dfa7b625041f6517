"""Per-part wall / CPU / main-thread CPU of final-pass steps by (torch threads, compositor bands), alternating
blocks in one process (t1c1: 1 and 1, t1c2: torch 1 and 2 bands, t2c2: 2 and 2).

python3 stepparts.py SNAP.pkl BLOCKS STEPS_PER_BLOCK full|coarse [t1c1,t1c2,...]
"""

import collections
import json
import os
import pickle
import sys
import time

import torch

from gsslam import imaging
from gsslam.mapping import rasterize_cpu as RC
from gsslam.mapping.final_pass import epoch_picker
from gsslam.mapping.window import adam_steps

snap, blocks, per, kind = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
with open(snap, "rb") as f:
    state = pickle.load(f)
acc = collections.defaultdict(lambda: [0.0, 0.0, 0.0])  # (threads, part) -> [wall, cpu, main-thread cpu]
cur = {"t": "t1c1"}
CONFIGS = {"t1c1": (1, 1), "t1c2": (1, 2), "t2c2": (2, 2)}
names = sys.argv[5].split(",") if len(sys.argv) > 5 else list(CONFIGS)


def timed(cls, name, part):
    fn = getattr(cls, name)

    def w(*a, **k):
        t, c, m = time.perf_counter(), time.process_time(), time.thread_time()
        r = fn(*a, **k)
        key = (cur["t"], part)
        acc[key][0] += time.perf_counter() - t
        acc[key][1] += time.process_time() - c
        acc[key][2] += time.thread_time() - m
        return r

    setattr(cls, name, staticmethod(w))


timed(RC._CompositeCPU, "forward", "composite fwd")
timed(RC._CompositeCPU, "backward", "composite bwd")
timed(RC._ProjectCPU, "forward", "project fwd")
timed(RC._ProjectCPU, "backward", "project bwd")
timed(imaging._SSIMRender, "forward", "ssim fwd")
timed(imaging._SSIMRender, "backward", "ssim bwd")
pick = epoch_picker(state, list(state.order))
coarse = per if kind == "coarse" else 0
load0 = os.getloadavg()[0]
for b in range(blocks):
    for t in names if b % 2 == 0 else names[::-1]:
        cur["t"] = t
        torch.set_num_threads(CONFIGS[t][0])
        w0, c0, m0 = time.perf_counter(), time.process_time(), time.thread_time()
        with RC.compositor_threads(CONFIGS[t][1]):
            adam_steps(state, per, pick, [], list(state.order), lr_scale=0.3, coarse_steps=coarse)
        acc[(t, "step")][0] += time.perf_counter() - w0
        acc[(t, "step")][1] += time.process_time() - c0
        acc[(t, "step")][2] += time.thread_time() - m0
n = blocks * per
parts = sorted({p for _, p in acc})
out = {"kind": kind, "steps_each": n, "load": [round(load0, 1), round(os.getloadavg()[0], 1)]}
base = names[0]
for p in parts:
    w1, c1, m1 = acc[(base, p)]
    row = {}
    for t in names:
        w, c, m = acc[(t, p)]
        row[t] = {
            "wall_ms": round(1e3 * w / n, 2),
            "cpu_ms": round(1e3 * c / n, 2),
            "main_cpu_ms": round(1e3 * m / n, 2),
            "wall_ratio": round(w / w1, 3) if w1 else None,
            "main_cpu_over_base_cpu": round(m / c1, 3) if c1 else None,
        }
    out[p] = row
print(json.dumps(out, indent=1))
