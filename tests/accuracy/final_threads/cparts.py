"""Each C call of the compositor (count, fill, forward, backward, span_rows) at 1 vs 2 bands: process CPU
and main-thread CPU per call, full final-pass steps on the snapshot, alternating blocks."""

import collections
import os
import pickle
import sys
import time

import torch

from gsslam.mapping import rasterize_cpu as RC
from gsslam.mapping.final_pass import epoch_picker
from gsslam.mapping.window import adam_steps

torch.set_num_threads(1)
state = pickle.load(open(sys.argv[1], "rb"))
blocks, per = int(sys.argv[2]), int(sys.argv[3])
acc = collections.defaultdict(lambda: [0.0, 0.0, 0.0])
cur = {"b": 1}
RC._load()
real = RC._lib


class Proxy:
    def __getattr__(self, name):
        fn = getattr(real, name)

        def w(*a):
            t, c, m = time.perf_counter(), time.process_time(), time.thread_time()
            r = fn(*a)
            k = (cur["b"], name.rsplit("_", 1)[0])
            acc[k][0] += time.perf_counter() - t
            acc[k][1] += time.process_time() - c
            acc[k][2] += time.thread_time() - m
            return r

        return w


RC._lib = Proxy()
pick = epoch_picker(state, list(state.order))
for b in range(blocks):
    for n in (1, 2) if b % 2 == 0 else (2, 1):
        cur["b"] = n
        with RC.compositor_threads(n):
            adam_steps(state, per, pick, [], list(state.order), lr_scale=0.3)
N = blocks * per
print("load", os.getloadavg()[0])
for name in sorted({k for _, k in acc}):
    w1, c1, m1 = acc[(1, name)]
    w2, c2, m2 = acc[(2, name)]
    print(
        f"{name:22s} 1 band cpu {1e3 * c1 / N:6.2f} ms | 2 bands cpu {1e3 * c2 / N:6.2f} main {1e3 * m2 / N:6.2f} ms (main/1-band {m2 / max(c1, 1e-9):.3f}) wall {1e3 * w1 / N:6.2f} -> {1e3 * w2 / N:6.2f}"
    )
