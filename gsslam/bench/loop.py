"""``gsslam bench loop``: loop-detection time per submap as the map grows.

Worst case for the spatial prefilter: every submap lies in the same textured room (a camera
circling many times), so all bounding spheres intersect and only the appearance ranking bounds
how many submaps get the reprojection test. A pool of ray-cast submaps is reused with fresh ids
and slightly perturbed world transforms until the map holds ``n`` submaps; then ``detect`` is
timed for the next submaps: ``candidates_ms`` is the detection stage alone (prefilters and
reprojection overlap), ``detect_ms_per_submap`` adds verification of up to ``max_candidates``
loops. Every new submap here really is a revisit, so verification always runs.
"""

from __future__ import annotations

import time

import numpy as np

from gsslam.config import LoopConfig
from gsslam.datasets.synthetic import block_room, make_submaps
from gsslam.datasets.synthetic.trajectories import outward_circle
from gsslam.geometry import make_T, so3_exp
from gsslam.loop.detector import LoopDetector

POOL_SUBMAPS = 12  # distinct submaps (two turns of the circle)
TIMED = 5  # detect() calls timed per size


def _grow(det: LoopDetector, pool, poses: dict, n: int, rng: np.random.Generator) -> None:
    while len(det) < n:
        k = len(det)
        p = k % len(pool.encodings)
        det.add_submap(k, pool.encodings[p], pool.images[p])
        jitter = make_T(so3_exp(0.01 * rng.standard_normal(3)), 0.02 * rng.standard_normal(3))
        poses[k] = pool.T_world_local_gt[p] @ jitter


def run(sizes: list[int], mode: str = "rgbd") -> dict:
    cfg = LoopConfig()
    rng = np.random.default_rng(0)
    pool = make_submaps(block_room(seed=1), outward_circle(6 * POOL_SUBMAPS + 1, 2.0), mono=False)
    out: dict = {
        "mode": mode,
        "config": {
            "max_reprojection_checks": cfg.max_reprojection_checks,
            "points_per_submap": cfg.points_per_submap,
            "orb_features": cfg.orb_features,
        },
        "sizes": {},
    }
    for n in sorted(sizes):
        det = LoopDetector(cfg, mode=mode)
        poses: dict[int, np.ndarray] = {}
        t0 = time.perf_counter()
        _grow(det, pool, poses, n, rng)
        add_s = (time.perf_counter() - t0) / max(1, n)
        times, cand_times, loops = [], [], 0
        for _ in range(TIMED):
            _grow(det, pool, poses, len(det) + 1, rng)
            t = time.perf_counter()
            det.candidates(len(det) - 1, poses)
            cand_times.append(time.perf_counter() - t)
            t = time.perf_counter()
            loops += len(det.detect(len(det) - 1, poses))
            times.append(time.perf_counter() - t)
        out["sizes"][str(n)] = {
            "detect_ms_per_submap": round(1e3 * float(np.median(times)), 2),
            "detect_ms_max": round(1e3 * float(np.max(times)), 2),
            "candidates_ms": round(1e3 * float(np.median(cand_times)), 2),
            "add_submap_ms": round(1e3 * add_s, 2),
            "loops_found": loops,
        }
    return out
