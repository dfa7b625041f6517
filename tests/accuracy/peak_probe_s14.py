"""Session 14 (issue #17): where the resident memory peaks. A sampler thread records RSS and the main thread's innermost
frame every 0.1 s (teddy 200 played fbfbfb, RGB-D). PYTHONPATH=. python3 tests/accuracy/peak_probe_s14.py N OUT.json [map|nomap] [k=v ...]"""
import sys, threading, time, json, tempfile
from pathlib import Path
n, out = int(sys.argv[1]), sys.argv[2]; mode_map = sys.argv[3] == "map"; over = sys.argv[4:]
from gsslam.config import load_config
from gsslam.datasets.base import open_dataset
from gsslam.run.sequence import run_dataset
from gsslam.run.memory import rss_mb, peak_rss_mb
main = threading.main_thread().ident
import os, ctypes
if os.environ.get("TRIM") == "1":
    import gsslam.slam.pipeline as P
    libc = ctypes.CDLL("libc.so.6")
    orig = P.Pipeline._encode_window
    def enc(self):
        orig(self); libc.malloc_trim(0)
    P.Pipeline._encode_window = enc
samples = []; stop = False
def where():
    f = sys._current_frames().get(main); stack = []
    while f is not None:
        fn = f.f_code.co_filename
        if "/gsslam/" in fn or "/factors/" in fn:
            stack.append(f"{fn.split('/gsslam/')[-1]}:{f.f_code.co_name}:{f.f_lineno}")
        f = f.f_back
    return stack[:4]
def sampler():
    while not stop:
        samples.append((round(time.time() - t0, 2), round(rss_mb(), 1), where())); time.sleep(0.1)
t0 = time.time()
th = threading.Thread(target=sampler, daemon=True); th.start()
ds = open_dataset("playback", Path("/work/shared/data/rgbd_dataset_freiburg3_teddy"), base="tum", pattern="fbfbfb")
base = [] if mode_map else ["mapper.enabled=false", "loop.enabled=false"]
cfg = load_config(None, [*base, *over], mode="rgbd")
with tempfile.TemporaryDirectory() as tmp:
    m = run_dataset(ds, cfg, Path(tmp), max_frames=n).metrics
stop = True; th.join()
peak = max(samples, key=lambda s: s[1])
print("peak sampled", peak, "VmHWM", peak_rss_mb(), "metrics peak", m.get("peak_rss_mb"))
top = sorted(samples, key=lambda s: -s[1])[:15]
for s in top: print(s)
json.dump(samples, open(out, "w"))
