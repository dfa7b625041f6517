"""Loop closure inside the pipeline: detect after every submap, add, optimise, check, remove.

After submap ``i`` has been added to its chain's graph and the graph updated
(:meth:`LoopStage.after_submap`):

0. RGB-D with ``loop.icp_neighbours = n`` (loop closure on or off): dense ICP relative poses from submap
   ``i`` to submaps ``i-n .. i-1`` (:func:`gsslam.loop.icp_loop.neighbour_icp`) enter the graph, one update;
1. the loop detector of the chain registers the submap (compact record: points, tiny images, ORB);
2. ``detect(i, poses)`` against the graph's current ``T_world_local`` returns verified loops that
   passed the drift gate; each goes into the graph as one point factor (``SubmapGraph.add_loop``;
   mono: in submap-i units, noise along / across the rays from the loop's own inlier residual and a
   DCS kernel, :mod:`gsslam.loop.weights`);
   or, RGB-D with ``loop.icp_refine``, as a relative pose refined by dense ICP of its closest keyframe
   pair with the ICP information (``SubmapGraph.add_loop_pose``, :mod:`gsslam.loop.icp_loop`);
3. one iSAM2 update; ``check_loops`` names loops the optimised graph could not satisfy or that
   conflict with the others; they are removed and the graph updated again
   (``update(extra_iterations=10)``);
4. the pipeline then moves the Gaussian map with the new estimates (``MapStage.follow_graph``).

Loops are searched inside one chain (each chain has its own graph and submap ids). Across chains,
:meth:`LoopStage.relocalize` places a new chain in the world frame of an earlier one: RGB-D rigidly
(:mod:`gsslam.loop.relocalize` + ICP), mono by a Sim(3) (:mod:`gsslam.loop.chain_sim3`: the new
chain has its own scale). The chains then share one world frame (their graphs stay separate).
"""

from __future__ import annotations

import dataclasses
import logging

import cv2
import numpy as np

from gsslam.config import LoopConfig
from gsslam.geometry import sim3_scale
from gsslam.types import Frame, SubmapEncoding

log = logging.getLogger(__name__)

ICP_MIN_FITNESS = 0.1  # share of the new submap's points that meet the earlier chain's surface
ICP_MAX_ROT_DEG = 5.0  # ICP refines the verified estimate; a larger move means it slid away


def close_to(T_a: np.ndarray, T_b: np.ndarray, max_trans: float) -> bool:
    """Whether two rigid transforms differ by less than ``max_trans`` and ``ICP_MAX_ROT_DEG``."""
    D = np.linalg.inv(T_b) @ T_a
    angle = np.degrees(np.arccos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1.0, 1.0)))
    return bool(np.linalg.norm(D[:3, 3]) < max_trans and angle < ICP_MAX_ROT_DEG)


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
        self.relocalized: list[dict] = []  # chains placed in the world frame by re-localization
        self._reloc_rng = np.random.default_rng(seed + 7919)
        self._across: dict[tuple[int, int], list] = {}  # (new chain, earlier chain) -> verified loops (mono)
        self.icp_refined = 0  # RGB-D loops that entered the graph as ICP relative poses
        self.icp_refused = 0  # ... and those whose ICP was refused (they keep the point factor)
        self.icp_neighbour_factors = 0  # ICP relative poses to neighbouring submaps (icp_neighbours)

    def _detector(self, cid: int):
        if cid not in self._detectors:
            from gsslam.loop import LoopDetector

            self._detectors[cid] = LoopDetector(self.cfg, mode=self.mode, seed=self.seed + cid)
            self._loops[cid] = {}
        return self._detectors[cid]

    def after_submap(self, chain, cid: int, sid: int, enc: SubmapEncoding, frames: list[Frame]) -> bool:
        """Register submap ``sid``, close loops; returns True when the graph was updated."""
        near = self._icp_neighbours(chain, sid)  # RGB-D with loop.icp_neighbours (loop/icp_loop.py)
        if not self.cfg.enabled:
            return near
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
            return near
        from gsslam.loop.weights import loop_weight

        loops = self._loops[cid]
        for lc in new:  # mono: each loop weighs by its own inlier residual (loop/weights.py)
            icp = self._refine_icp(chain, lc)  # RGB-D with loop.icp_refine: dense ICP (loop/icp_loop.py)
            if icp is not None:
                loops[graph.add_loop_pose(lc.i, lc.m, icp.T_i_m, icp.information, self.cfg.icp_huber)] = lc
                continue
            w = loop_weight(lc, self.mode, self.cfg)  # submap-i units (mono) or None (RGB-D)
            if w is None:
                h_ = graph.add_loop(lc.i, lc.m, lc.X_i, lc.X_m)
            else:
                h_ = graph.add_loop(
                    lc.i, lc.m, lc.X_i, lc.X_m, sigma=w.sigma, local_units=True, sigma_perp=w.sigma_perp,
                    dcs_phi=w.dcs_phi, views=(lc.view_i, lc.view_m),
                )  # fmt: skip
            loops[h_] = lc
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

    def _icp_neighbours(self, chain, sid: int) -> bool:
        """RGB-D with ``loop.icp_neighbours``: ICP relative poses from submap ``sid`` to its predecessors
        enter the graph (one update); True when any did."""
        if self.mode != "rgbd" or self.cfg.icp_neighbours <= 0 or sid >= len(chain.encodings):
            return False
        from gsslam.loop.icp_loop import neighbour_icp

        graph = chain.graph
        poses = {k: graph.submap_pose(k) for k in range(max(0, sid - self.cfg.icp_neighbours), sid + 1)}
        pairs = neighbour_icp(sid, chain.encodings, poses, self.cfg)
        for j, icp in pairs:
            graph.add_loop_pose(sid, j, icp.T_i_m, icp.information, self.cfg.icp_huber)
        self.icp_neighbour_factors += len(pairs)
        if pairs:
            graph.update()
        return bool(pairs)

    def _refine_icp(self, chain, lc):
        """RGB-D with ``loop.icp_refine``: the loop refined by dense ICP (:class:`IcpLoop`), or None."""
        if self.mode != "rgbd" or not self.cfg.icp_refine:
            return None
        encs = chain.encodings
        if max(lc.i, lc.m) >= len(encs):
            return None
        from gsslam.loop.icp_loop import refine_loop_icp

        icp = refine_loop_icp(lc, encs[lc.i], encs[lc.m], self.cfg)
        if icp is None:
            self.icp_refused += 1
            return None
        self.icp_refined += 1
        log.info("loop %d-%d refined by ICP (views %s, %d points, rms %.1f mm, moved %.1f mm / %.2f deg)",
                 lc.i, lc.m, icp.views, icp.inliers, 1e3 * icp.rmse_m, 1e3 * icp.shift_m, icp.shift_deg)  # fmt: skip
        return icp

    def relocalize(self, chains, cid: int, sid: int) -> np.ndarray | None:
        """``T_world_chain`` for chain ``cid`` from its submap ``sid`` verified against an earlier chain
        that is in the world frame, or None (loop closure must be enabled). RGB-D: rigid, refined by
        ICP; mono: a Sim(3) from every loop verified across the two chains so far."""
        if not self.cfg.enabled or cid not in self._detectors:
            return None
        for pid in range(cid):
            if pid not in self._detectors or not chains[pid].in_world or chains[pid].failed:
                continue
            if self.mode == "rgbd":
                T = self._place_rigid(chains, cid, sid, pid)
            else:
                T = self._place_sim3(chains, cid, sid, pid)
            if T is not None:
                return T
        return None

    def _place_sim3(self, chains, cid: int, sid: int, pid: int) -> np.ndarray | None:
        """Mono: ``T_world_chain`` of chain ``cid`` as a Sim(3) through chain ``pid`` (or None)."""
        from gsslam.loop.chain_sim3 import dense_points, fit_chain_sim3, refine_dense
        from gsslam.loop.relocalize import verified_against

        det_p = self._detectors[pid]
        c = self.cfg  # across a gap fewer matches survive in noisy mono point maps: the rejoin gates
        cfg = dataclasses.replace(
            c, min_inliers=c.rejoin_min_inliers, min_inlier_ratio=c.rejoin_min_inlier_ratio
        )
        rec_i = self._detectors[cid].record(sid)
        found = verified_against(rec_i, det_p.records(), cfg, self.mode, self._reloc_rng)
        if not found:
            return None
        pool = self._across.setdefault((cid, pid), [])
        pool.extend(found)
        gc, gp = chains[cid].graph, chains[pid].graph
        S_new = {k: gc.submap_pose(k) for k in {lc.i for lc in pool}}
        S_old = {k: gp.submap_pose(k) for k in {lc.m for lc in pool}}
        depth_old = np.median([det_p.record(lc.m).median_depth * sim3_scale(S_old[lc.m]) for lc in pool])
        thr = self.cfg.inlier_threshold_rel * depth_old  # earlier-chain units
        fit = fit_chain_sim3(pool, S_new, S_old, thr, self.cfg.ransac_iterations, self._reloc_rng)
        if fit is None or fit.inliers < self.cfg.rejoin_min_inliers:
            return None
        spacing = thr / 5  # earlier-chain units
        pts_old = dense_points(chains[pid].encodings, {k: gp.submap_pose(k) for k in range(gp.num_submaps)},
                               spacing)  # fmt: skip
        S_all = {k: gc.submap_pose(k) for k in range(min(gc.num_submaps, len(chains[cid].encodings)))}
        pts_new = dense_points(chains[cid].encodings, S_all, spacing / fit.scale)
        fit, fitness = refine_dense(fit, pts_old, pts_new, thr, self.cfg.rejoin_min_fitness)
        if fit is None:
            log.info("chain %d: Sim(3) to chain %d not confirmed by the dense maps (fitness %s)", cid, pid,
                     None if fitness is None else round(fitness, 3))  # fmt: skip
            return None
        best = found[0]
        self.relocalized.append(
            {
                "chain": cid,
                "submap": sid,
                "to_chain": pid,
                "to_submap": best.m,
                "inliers": fit.inliers,
                "icp_fitness": fitness,
                "scale": fit.scale,
                "loops": fit.loops,
                "rms": fit.rms,
            }  # fmt: skip
        )
        log.info("mono chain %d re-joined to chain %d by Sim(3) (%d loops, %d/%d inliers, scale %.3f)",
                 cid, pid, fit.loops, fit.inliers, fit.pairs, fit.scale)  # fmt: skip
        return chains[pid].T_world_chain @ fit.T_old_new

    def _place_rigid(self, chains, cid: int, sid: int, pid: int) -> np.ndarray | None:
        """RGB-D: ``T_world_chain`` of chain ``cid`` through chain ``pid`` (or None)."""
        from gsslam.geometry import invert_T
        from gsslam.loop.relocalize import relocalize

        rec_i = self._detectors[cid].record(sid)
        loop = relocalize(rec_i, self._detectors[pid].records(), self.cfg, self.mode, self._reloc_rng)
        if loop is None:
            return None
        # in chain pid's frame: submap i of chain cid sits at T_p_i (RANSAC), refined by ICP against
        # the dense points of every submap of chain pid
        gp = chains[pid].graph
        T_p_i, fitness = gp.submap_pose(loop.m) @ invert_T(loop.T_i_m), None
        if sid < len(chains[cid].encodings) and chains[pid].encodings:
            from gsslam.loop.relocalize import local_points, refine_rigid

            thr = self.cfg.inlier_threshold_m  # ICP gate: the loop inlier distance (metres)
            pts_i = local_points(chains[cid].encodings[sid], thr / 5)
            pts_p = []
            for k, enc in enumerate(chains[pid].encodings):
                T = gp.submap_pose(k)
                pts_p.append(local_points(enc, thr / 5) @ T[:3, :3].T + T[:3, 3])
            pts_p = np.concatenate(pts_p)
            if len(pts_i) >= 100 and len(pts_p) >= 100:
                T_ref, fitness = refine_rigid(T_p_i, pts_p, pts_i, thr)
                T_ref, _ = refine_rigid(T_ref, pts_p, pts_i, thr / 2)  # then a tighter gate
                if fitness >= ICP_MIN_FITNESS and close_to(T_ref, T_p_i, 2 * thr):
                    T_p_i = T_ref  # else the RANSAC estimate stays
        T_world_i = chains[pid].T_world_chain @ T_p_i
        self.relocalized.append(
            {
                "chain": cid,
                "submap": sid,
                "to_chain": pid,
                "to_submap": loop.m,
                "inliers": len(loop),
                "icp_fitness": fitness,
            }  # fmt: skip
        )
        log.info("chain %d re-localized against chain %d (submap %d-%d, %d inliers)",
                 cid, pid, sid, loop.m, len(loop))  # fmt: skip
        return T_world_i @ invert_T(chains[cid].graph.submap_pose(sid))

    def metrics(self) -> dict:
        """Loop counters summed over chains (``LoopStats.to_dict`` fields) and the loops in the graphs."""
        out: dict = {k: 0 for k in _STAT_KEYS}
        out["enabled"] = self.cfg.enabled
        out["loops"] = []
        out["unverified"] = {}
        detect_ms, checked = 0.0, 0
        for det in self._detectors.values():
            d = det.stats.to_dict()
            for k in _STAT_KEYS:
                out[k] += d[k]
            for why, n in d["unverified"].items():
                out["unverified"][why] = out["unverified"].get(why, 0) + n
            out["loops"] += d["loops"]
            detect_ms += det.stats.detect_seconds * 1e3
            checked += det.stats.submaps_checked
        out["mean_detect_ms"] = detect_ms / max(1, checked)
        out["in_graph"] = sum(len(v) for v in self._loops.values())
        out["relocalized"] = list(self.relocalized)
        out["icp_refined"], out["icp_refused"] = self.icp_refined, self.icp_refused
        out["icp_neighbour_factors"] = self.icp_neighbour_factors
        return out
