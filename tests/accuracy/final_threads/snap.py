"""Run a teddy RGB-D default run up to the final pass; pickle the MapState (after follow_graph) and stop."""

import logging
import pickle
import sys
import tempfile
import time
from pathlib import Path

from gsslam.config import load_config
from gsslam.datasets.base import open_dataset
from gsslam.mapping import mapper as M
from gsslam.run.sequence import run_dataset

path, out = sys.argv[1], sys.argv[2]
over = sys.argv[3:]


class Stop(Exception):
    pass


def fake_finalize(self, *a, **k):
    with open(out, "wb") as f:
        pickle.dump(self.map, f)
    raise Stop()


M.GaussianMapper.finalize = fake_finalize
logging.basicConfig(level=logging.WARNING)
ds = open_dataset("tum", path)
cfg = load_config(None, over, mode="rgbd")
t0, c0 = time.perf_counter(), time.process_time()
try:
    with tempfile.TemporaryDirectory() as tmp:
        run_dataset(ds, cfg, Path(tmp))
except Stop:
    pass
print("snapshot", out, "wall", time.perf_counter() - t0, "cpu", time.process_time() - c0)
