"""Session 14 (issue #17): what a run holds, by attribute path, at 200 / 500 / 1000 frames of one run.

Walks the Pipeline object (attributes, dicts, lists; numpy arrays and torch tensors counted once per
buffer) at those frame counts of teddy 200 played fbfbfb (RGB-D, defaults: map and loops on), with the C
heap's in-use / free bytes (glibc ``mallinfo2``) and the resident size; ``--table`` prints the
docs/results.md table ("Memory flat in length, session 14") from the JSON it wrote.

    PYTHONPATH=. python3 tests/accuracy/memory_probe_s14.py 1000 OUT.json map
    python3 tests/accuracy/memory_probe_s14.py --table OUT.json
"""

import sys

if sys.argv[1] == "--table":
    sys.argv = sys.argv[1:]
    import json

    s = json.load(open(sys.argv[1]))
    snaps = [x for x in s if x["tag"] == "frames"]
    groups = [
        (
            "submap depths (encodings' packed Z, 320x240 float32; keyframe depths are views)",
            ["pipe.keyframes[*].depth", "pipe.chains[*].encodings[*]._points_cam_z"],
        ),
        (
            "submap confidences (uint8 codes)",
            [
                "pipe.chains[*].encodings[*]._confidence_codes",
                "pipe.chains[*].encodings[*]._confidence_values",
            ],
        ),
        ("mapper keyframe images (160x120x3 float32)", ["pipe.map_stage.mapper.map.keyframes[*].image"]),
        ("mapper keyframe depths (160x120 float32)", ["pipe.map_stage.mapper.map.keyframes[*].depth"]),
        ("mapper stored flows (160x120x2 float32 + valid)", ["pipe.map_stage.mapper.map.flows[*][*]"]),
        ("graph replay log (factor specs, values)", ["pipe.chains[*].graph.backend._log[*][*][*][*]"]),
        ("loop database (records, features, appearance)", ["pipe.loop_stage._detectors"]),
        ("accepted loops (points, views)", ["pipe.loop_stage._loops"]),
        (
            "Gaussian map (model + densify state)",
            ["pipe.map_stage.mapper.map.model", "pipe.map_stage.mapper.map.densify_state"],
        ),
        (
            "frames held for tracking/encoding (full-res float32 images + depths)",
            ["pipe.prev_frames", "pipe.window", "pipe.last_good", "pipe.tracker"],
        ),
        ("flow cache (weakly keyed)", ["pipe.cross_flow.flow.cache"]),
        ("per-frame poses and relations", ["pipe.online_poses", "pipe.relative", "pipe.keyframe_relative"]),
    ]

    def mb(snap, prefixes):
        return sum(v[0] for k, v in snap["by_path"].items() if any(k.startswith(p) for p in prefixes))

    used = set()
    print(
        "| component | "
        + " | ".join(f"{x['frames']} frames ({x['keyframes']} kf)" for x in snaps)
        + " | MB per 100 frames (200 -> %d) |" % snaps[-1]["frames"]
    )
    print("|---|" + "---|" * (len(snaps) + 1))
    df = (snaps[-1]["frames"] - snaps[0]["frames"]) / 100
    for name, pre in groups:
        vals = [mb(x, pre) for x in snaps]
        print(f"| {name} | " + " | ".join(f"{v:.1f}" for v in vals) + f" | {(vals[-1] - vals[0]) / df:.2f} |")
    allp = [p for _, pre in groups for p in pre]
    rest = [x["arrays_mb"] - mb(x, allp) for x in snaps]
    print(
        "| other arrays | " + " | ".join(f"{v:.1f}" for v in rest) + f" | {(rest[-1] - rest[0]) / df:.2f} |"
    )
    for key, name in [
        ("arrays_mb", "**all arrays and tensors the pipeline holds**"),
        ("malloc_in_use_mb", "C heap in use (glibc mallinfo2 uordblks)"),
        ("malloc_free_mb", "C heap free but kept (fordblks)"),
        ("rss_mb", "**resident (RSS)**"),
    ]:
        vals = [x[key] for x in snaps]
        print(f"| {name} | " + " | ".join(f"{v:.1f}" for v in vals) + f" | {(vals[-1] - vals[0]) / df:.2f} |")
    inv = [x["malloc_in_use_mb"] - x["arrays_mb"] for x in snaps]
    print(
        "| heap in use not in arrays (gtsam's iSAM2, factor closures, Python objects) | "
        + " | ".join(f"{v:.1f}" for v in inv)
        + f" | {(inv[-1] - inv[0]) / df:.2f} |"
    )
    sys.exit(0)

import ctypes
import gc
import json
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

n_frames = int(sys.argv[1])
out_json = sys.argv[2]
mode_map = sys.argv[3] == "map"
over = sys.argv[4:]
AT = {200, 500, 1000, n_frames}

import torch

import gsslam.slam.pipeline as P
from gsslam.config import load_config
from gsslam.datasets.base import open_dataset
from gsslam.run.memory import rss_mb
from gsslam.run.sequence import run_dataset

libc = ctypes.CDLL("libc.so.6")


class MI2(ctypes.Structure):
    _fields_ = [
        (n, ctypes.c_size_t)
        for n in (
            "arena",
            "ordblks",
            "smblks",
            "hblks",
            "hblkhd",
            "usmblks",
            "fsmblks",
            "uordblks",
            "fordblks",
            "keepcost",
        )
    ]


libc.mallinfo2.restype = MI2


def norm(path):
    return re.sub(r"\[[^\]]*\]", "[*]", path)


def walk(root):
    seen_obj = set()
    seen_buf = set()
    by_path = {}
    counts = {}
    other_types = {}
    stack = [(root, "pipe", 0)]
    while stack:
        o, path, depth = stack.pop()
        if id(o) in seen_obj or depth > 40:
            continue
        if (
            isinstance(o, (int, float, str, bytes, bool, type(None), type))
            or callable(o)
            and not hasattr(o, "__dict__")
        ):
            continue
        seen_obj.add(id(o))
        key = norm(path)
        if isinstance(o, np.ndarray):
            base = o
            while isinstance(base.base, np.ndarray):
                base = base.base
            ptr = base.__array_interface__["data"][0]
            if ptr not in seen_buf:
                seen_buf.add(ptr)
                by_path[key] = by_path.get(key, 0) + base.nbytes
                counts[key] = counts.get(key, 0) + 1
            continue
        if isinstance(o, torch.Tensor):
            st = o.untyped_storage()
            ptr = st.data_ptr()
            if ptr not in seen_buf:
                seen_buf.add(ptr)
                by_path[key] = by_path.get(key, 0) + st.nbytes()
                counts[key] = counts.get(key, 0) + 1
            if o.grad is not None:
                stack.append((o.grad, path + ".grad", depth + 1))
            continue
        if isinstance(o, dict):
            for k, v in o.items():
                stack.append((v, f"{path}[{k!r}]", depth + 1))
            continue
        if isinstance(o, (list, tuple, set, frozenset)):
            for i, v in enumerate(o):
                stack.append((v, f"{path}[{i}]", depth + 1))
            continue
        mod = type(o).__module__ or ""
        if mod.startswith("gtsam") or "gtsam" in type(o).__name__.lower():
            t = f"{type(o).__name__} @ {key}"
            other_types[t] = other_types.get(t, 0) + 1
            continue
        d = None
        try:
            d = vars(o)
        except TypeError:
            pass
        if d is not None:
            for k, v in d.items():
                stack.append((v, f"{path}.{k}", depth + 1))
        slots = getattr(type(o), "__slots__", ())
        for s in slots if isinstance(slots, (list, tuple)) else ():
            if hasattr(o, s):
                stack.append((getattr(o, s), f"{path}.{s}", depth + 1))
        if d is None and not slots:
            t = f"{type(o).__module__}.{type(o).__name__} @ {key}"
            other_types[t] = other_types.get(t, 0) + 1
    return by_path, counts, other_types


snaps = []
orig = P.Pipeline.process


def process(self, frame, retry=False):
    r = orig(self, frame, retry)
    if not retry and self.n_frames in AT and not any(s["frames"] == self.n_frames for s in snaps):
        snap(self, self.n_frames)
    return r


P.Pipeline.process = process


def snap(pipe, n, tag="frames"):
    t = time.time()
    gc.collect()
    by_path, counts, other = walk(pipe)
    mi = libc.mallinfo2()
    s = {
        "frames": n,
        "tag": tag,
        "rss_mb": rss_mb(),
        "keyframes": len(pipe.keyframes),
        "arrays_mb": sum(by_path.values()) / 2**20,
        "malloc_in_use_mb": mi.uordblks / 2**20,
        "malloc_free_mb": mi.fordblks / 2**20,
        "mmap_mb": mi.hblkhd / 2**20,
        "by_path": {
            k: [round(v / 2**20, 3), counts[k]] for k, v in sorted(by_path.items(), key=lambda x: -x[1])
        },
        "other": other,
        "gc_objects": len(gc.get_objects()),
        "walk_s": time.time() - t,
    }
    snaps.append(s)
    print(
        f"snapshot {n}: rss {s['rss_mb']:.0f} MB, arrays {s['arrays_mb']:.0f} MB, malloc in use {s['malloc_in_use_mb']:.0f} free {s['malloc_free_mb']:.0f} mmap {s['mmap_mb']:.0f}, {s['walk_s']:.1f} s",
        flush=True,
    )
    json.dump(snaps, open(out_json, "w"), indent=1)


orig_finish = P.Pipeline.finish


def finish(self, *a, **k):
    snap(self, self.n_frames, "before finish")
    r = orig_finish(self, *a, **k)
    snap(self, self.n_frames, "after finish")
    return r


P.Pipeline.finish = finish

ds = open_dataset(
    "playback", Path("/work/shared/data/rgbd_dataset_freiburg3_teddy"), base="tum", pattern="fbfbfb"
)
base = [] if mode_map else ["mapper.enabled=false", "loop.enabled=false"]
cfg = load_config(None, [*base, *over], mode="rgbd")
with tempfile.TemporaryDirectory() as tmp:
    m = run_dataset(ds, cfg, Path(tmp), max_frames=n_frames).metrics
print("ate", m["ate"]["rmse_m"], "kf", m["keyframes"])
