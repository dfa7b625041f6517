"""Measuring tool (docs/results.md, "Corrections inside submaps, session 7"), not a test: run one row of the
tracking suite in process (map off) and keep the pipeline after ``close_chain`` (before the final batch) as a
checkpoint in OUT; ``evalkeep.py OUT`` then finishes it with and without ``graph.keyframe_refine``.
Usage: ``PYTHONPATH=. python keep.py SEQ MODE on|off OUT [MAX_FRAMES|-] [key=value ...]``, e.g.
``keep.py teddy200_fbf rgbd on /tmp/kfr/runs/teddy200_fbf_rgbd_on``."""
import sys, json, time, logging, yaml
from pathlib import Path
from gsslam.config import load_config
from gsslam.datasets.base import open_dataset
from gsslam.slam.pipeline import Pipeline
from gsslam.run.checkpoint import save_checkpoint
FBF = dict(base="tum", pattern="fbf", pause_every=97, pause_len=15, jump_every=151, jump_len=4, seed=0)
D = "../shared/data/rgbd_dataset_freiburg3_teddy"
SEQ = {
    "teddy200": ("tum", D, {}),
    "teddy200_fbf": ("playback", D, FBF),
    "teddy200_fbf_7scenes": ("playback", D, dict(FBF, misregister=dict(baseline_m=0.025, focal_scale=1.114, report="depth"))),
    "teddy200_fbf_misreg": ("playback", D, dict(FBF, misregister=dict(baseline_m=0.025, focal_scale=1.114))),
    "teddy200_s2_blur": ("playback", D, dict(base="tum", pattern="fbfbf", stride=2,
                         degrade=dict(shutter=0.5, exposure_amp=0.25, exposure_period=150))),  # MAX_FRAMES 300
    "synth_loop800": ("synthetic", None, dict(n_frames=800, width=320, height=240, trajectory="loop", seed=5)),
}
def open_seq(name, mode, out):
    ds, path, kw = SEQ[name]
    kw = dict(kw)
    if path is None:
        path = out / "synthetic.yaml"; path.write_text(yaml.safe_dump(kw)); kw = {}
    if mode == "mono" and ds == "tum":
        kw["with_depth"] = False
    return open_dataset(ds, path, **kw)
if __name__ == "__main__":
    name, mode, loops, out = sys.argv[1], sys.argv[2], sys.argv[3], Path(sys.argv[4])
    maxf = int(sys.argv[5]) if len(sys.argv) > 5 and sys.argv[5] != "-" else None
    extra = sys.argv[6:]
    out.mkdir(parents=True, exist_ok=True)
    logging.basicConfig(level=logging.WARNING)
    ds = open_seq(name, mode, out)
    cfg = load_config(None, ["mapper.enabled=false", f"loop.enabled={'true' if loops == 'on' else 'false'}", *extra], mode=mode)
    pipe = Pipeline(cfg, ds.intrinsics)
    n = len(ds) if maxf is None else min(maxf, len(ds))
    t0 = time.time()
    for i in range(n):
        pipe.process(ds[i])
    pipe.close_chain()
    save_checkpoint(out, pipe, {"next_frame": n, "frames_done": n, "seconds": time.time() - t0},
                    {"config_sha256": "kfr", "dataset": {"name": name, "mode": mode}})
    json.dump({"extra": extra, "name": name, "mode": mode, "loops": loops, "frames": n, "seconds": time.time() - t0}, open(out / "keep.json", "w"))
    print("done", name, mode, loops, n, time.time() - t0)
