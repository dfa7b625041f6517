"""Loop closure inside the pipeline: detect after every submap, add, optimise, check, remove.

After submap ``i`` has been added to its chain's graph and the graph updated
(:meth:`LoopStage.after_submap`):

1. the loop detector of the chain registers the submap (compact record: points, tiny images, ORB);
2. ``detect(i, poses)`` against the graph's current ``T_world_local`` returns verified loops that
   passed the drift gate; each goes into the graph as one point factor (``SubmapGraph.add_loop``);
3. one iSAM2 update; ``check_loops`` names loops the optimised graph could not satisfy or that
   conflict with the others; they are removed and the graph updated again
   (``update(extra_iterations=10)``);
4. the pipeline then moves the Gaussian map with the new estimates (``MapStage.follow_graph``).

Loops are searched inside one chain (each chain has its own graph and submap ids).
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from gsslam.config import LoopConfig
from gsslam.types import Frame, SubmapEncoding

log = logging.getLogger(__name__)

_STAT_KEYS = ("candidates", "detected", "accepted", "rejected", "rejected_after_optimisation")


class LoopStage:
    """One :class:`gsslam.loop.LoopDetector` per chain plus the graph handles of its accepted loops."""

    def __init__(self, cfg: LoopConfig, mode: str, seed: int = 0) -> None:
        self.cfg = cfg
        self.mode = mode
        self.seed = seed
        self._detectors: dict[int, object] = {}
        self._loops: dict[int, dict] = {}  # chain -> {graph handle: LoopConstraint}
        self.corrections = 0  # graph updates caused by loops

    def _detector(self, cid: int):
        if cid not in self._detectors:
            from gsslam.loop import LoopDetector

            self._detectors[cid] = LoopDetector(self.cfg, mode=self.mode, seed=self.seed + cid)
            self._loops[cid] = {}
        return self._detectors[cid]

    def after_submap(self, chain, cid: int, sid: int, enc: SubmapEncoding, frames: list[Frame]) -> bool:
        """Register submap ``sid``, close loops; returns True when the graph was updated."""
        if not self.cfg.enabled:
            return False
        det = self._detector(cid)
        h, w = enc.points_cam.shape[1:3]
        by_index = {f.index: f for f in frames}
        gray = np.stack(
            [cv2.resize(by_index[i].gray, (w, h), interpolation=cv2.INTER_AREA) for i in enc.frame_indices]
        ).astype(np.float32)
        det.add_submap(sid, enc, gray)
        graph = chain.graph
        poses = {k: graph.submap_pose(k) for k in range(graph.num_submaps)}
        new = det.detect(sid, poses)
        if not new:
            return False
        loops = self._loops[cid]
        for lc in new:
            loops[graph.add_loop(lc.i, lc.m, lc.X_i, lc.X_m)] = lc
        graph.update()
        poses = {k: graph.submap_pose(k) for k in range(graph.num_submaps)}
        bad = det.check_loops(loops, poses)
        for h_ in bad:
            graph.remove_factor(h_)
            lc = loops.pop(h_)
            log.info("loop %d-%d removed after optimisation", lc.i, lc.m)
        if bad:
            graph.update(extra_iterations=10)
        self.corrections += 1
        return True

    def metrics(self) -> dict:
        """Loop counters summed over chains (``LoopStats.to_dict`` fields) and the loops in the graphs."""
        out: dict = {k: 0 for k in _STAT_KEYS}
        out["enabled"] = self.cfg.enabled
        out["loops"] = []
        detect_ms, checked = 0.0, 0
        for det in self._detectors.values():
            d = det.stats.to_dict()
            for k in _STAT_KEYS:
                out[k] += d[k]
            out["loops"] += d["loops"]
            detect_ms += det.stats.detect_seconds * 1e3
            checked += det.stats.submaps_checked
        out["mean_detect_ms"] = detect_ms / max(1, checked)
        out["in_graph"] = sum(len(v) for v in self._loops.values())
        return out
