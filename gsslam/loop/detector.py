"""``LoopDetector``: SING3R-style loop closure between submaps, as a sequence of stages.

1. ``add_submap``: compress the submap (subsampled points, small depth maps, tiny-image
   descriptors, ORB features lifted to 3D) so per-submap state and cost stay bounded.
2. ``detect(i, poses)``: earlier submaps (older than ``skip_recent``) whose bounding sphere meets
   submap i's are ranked by appearance; the best ``max_reprojection_checks`` get the reprojection
   overlap test; candidates need overlap > ``min_overlap`` and
   ``0.7 * overlap + 0.3 * appearance > min_score``.
3. The best ``max_candidates`` are verified (ORB matches lifted to 3D, RANSAC Sim(3)/SE(3)).
4. Verified loops must pass the drift gate; they are returned as :class:`LoopConstraint` for the
   pipeline to add to the graph (this module never edits the graph).
5. After the graph update the pipeline calls ``check_loops`` and removes what it returns.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Hashable, Mapping

import numpy as np

from gsslam.config import LoopConfig
from gsslam.geometry import invert_T
from gsslam.loop.appearance import appearance_overlap
from gsslam.loop.consistency import check_loops, drift_gate, reject_inconsistent
from gsslam.loop.covisibility import make_record, reprojection_overlap, spheres_intersect, world_sphere
from gsslam.loop.types import LoopCandidate, LoopConstraint, LoopError, LoopStats, SubmapRecord
from gsslam.loop.verification import verify_candidate
from gsslam.types import SubmapEncoding

log = logging.getLogger(__name__)

W_POINTS, W_APPEARANCE = 0.7, 0.3


class LoopDetector:
    """Finds, verifies and sanity-checks loops; ``mode`` is "mono" (Sim(3)) or "rgbd" (SE(3))."""

    def __init__(self, cfg: LoopConfig, mode: str = "mono", seed: int = 0) -> None:
        if mode not in ("mono", "rgbd"):
            raise LoopError(f"mode must be 'mono' or 'rgbd', got {mode!r}")
        self.cfg = cfg
        self.mode = mode
        self.stats = LoopStats()
        self._rng = np.random.default_rng(seed)
        self._records: dict[int, SubmapRecord] = {}
        self._ids: list[int] = []
        self._app: list[np.ndarray] = []  # per record [V, D]
        self.odometry: dict[int, np.ndarray] = {}  # k -> T_prev_k as first seen by detect()

    def __len__(self) -> int:
        return len(self._records)

    def add_submap(self, submap_id: int, enc: SubmapEncoding, images: np.ndarray) -> None:
        """Register submap ``submap_id`` (ids increase along the trajectory).

        ``images``: [K+1, h, w] grayscale keyframes in [0, 1], one per ``enc.frame_indices``
        (any resolution with the point maps' aspect ratio; point-map resolution is enough).
        """
        if not self.cfg.enabled:
            return
        if submap_id in self._records:
            raise LoopError(f"submap {submap_id} was already added to the loop detector")
        if self._ids and submap_id < self._ids[-1]:
            raise LoopError(f"submap ids must increase: got {submap_id} after {self._ids[-1]}")
        rec = make_record(
            submap_id, enc, np.asarray(images), self.cfg.points_per_submap, self.cfg.orb_features, self._rng
        )
        self._records[submap_id] = rec
        self._ids.append(submap_id)
        self._app.append(rec.appearance)

    def record(self, submap_id: int) -> SubmapRecord:
        return self._records[submap_id]

    def records(self) -> list[SubmapRecord]:
        """Every registered submap's record, in the order they were added."""
        return [self._records[i] for i in self._ids]

    def candidates(self, i: int, poses: Mapping[int, np.ndarray]) -> list[LoopCandidate]:
        """Overlapping earlier submaps of submap ``i``, best score first (not yet verified)."""
        cfg = self.cfg
        if i not in self._records:
            raise LoopError(f"submap {i} is unknown to the loop detector; call add_submap first")
        rec_i = self._records[i]
        old = [k for k, sid in enumerate(self._ids) if sid < i - cfg.skip_recent and sid in poses]
        if not old:
            return []
        ids = [self._ids[k] for k in old]
        # 1. bounding spheres under the current estimate (vectorised over the map)
        c_i, r_i = world_sphere(rec_i, poses[i])
        spheres = [world_sphere(self._records[s], poses[s]) for s in ids]
        centers = np.array([c for c, _ in spheres])
        radii = np.array([r for _, r in spheres])
        near = spheres_intersect(c_i, r_i, centers, radii)
        if not near.any():
            return []
        ks = [old[j] for j in np.nonzero(near)[0]]
        # 2. appearance: best view pair per candidate, one matrix product
        V = len(rec_i.appearance)
        app_all = appearance_overlap(
            rec_i.appearance, np.concatenate([self._app[k] for k in ks])
        )  # [V, sum V_m]
        splits = np.cumsum([len(self._app[k]) for k in ks])[:-1]
        app = np.array([blk.max() for blk in np.split(app_all, splits, axis=1)]) if V else np.zeros(len(ks))
        order = np.argsort(-app)[: cfg.max_reprojection_checks]
        # 3. reprojection overlap and combined score
        out = []
        for j in order:
            m = self._ids[ks[j]]
            ratio, counts = reprojection_overlap(
                rec_i, poses[i], self._records[m], poses[m], cfg.depth_tolerance_rel, cfg.max_view_angle_deg
            )
            score = W_POINTS * ratio + W_APPEARANCE * float(app[j])
            if ratio <= cfg.min_overlap or score <= cfg.min_score:
                continue
            flat = np.argsort(-counts, axis=None)
            pairs = tuple(
                (int(a), int(b)) for a, b in zip(*np.unravel_index(flat, counts.shape)) if counts[a, b] > 0
            )
            out.append(LoopCandidate(i, m, ratio, float(app[j]), score, pairs))
        out.sort(key=lambda c: -c.score)
        return out[: cfg.max_candidates]

    def detect(self, i: int, poses: Mapping[int, np.ndarray]) -> list[LoopConstraint]:
        """Verified, drift-plausible loops of the current submap ``i``.

        ``poses``: submap id -> current [4, 4] ``T_world_local`` (Sim(3)) from the graph.
        """
        if not self.cfg.enabled:
            return []
        if i not in self._records:
            raise LoopError(f"submap {i} is unknown to the loop detector; call add_submap first")
        t0 = time.perf_counter()
        self._record_link(i, poses)
        accepted = []
        for cand in self.candidates(i, poses):
            self.stats.candidates += 1
            verdict = verify_candidate(
                cand, self._records[i], self._records[cand.m], self.cfg, self.mode, self._rng
            )
            loop = verdict.loop
            if loop is None:
                self.stats.unverified[verdict.why] = self.stats.unverified.get(verdict.why, 0) + 1
                log.debug(
                    "loop candidate %d-%d not verified: %s (%d matches, %d inliers)",
                    i, cand.m, verdict.why, verdict.matches, verdict.inliers,
                )  # fmt: skip
                continue
            self.stats.detected += 1
            ok, why = drift_gate(loop, poses, self.cfg)
            entry = {
                "i": i,
                "m": cand.m,
                "score": round(cand.score, 3),
                "overlap": round(cand.point_overlap, 3),
                "inliers": len(loop),
                "inlier_ratio": round(loop.inlier_ratio, 3),
                "accepted": ok,
                "why": why,
            }
            self.stats.log.append(entry)
            if not ok:
                self.stats.rejected += 1
                log.info("loop %d-%d refused by the drift gate: %s", i, cand.m, why)
                continue
            self.stats.accepted += 1
            log.info(
                "loop %d-%d accepted: %d inliers (%.0f%%), score %.2f",
                i,
                cand.m,
                len(loop),
                100 * loop.inlier_ratio,
                cand.score,
            )
            accepted.append(loop)
        self.stats.detect_seconds += time.perf_counter() - t0
        self.stats.submaps_checked += 1
        return accepted

    def _record_link(self, i: int, poses: Mapping[int, np.ndarray]) -> None:
        """Adjacency link prev -> i as the graph has it before any loop of i moves it."""
        k = self._ids.index(i)
        if i not in self.odometry and k > 0 and self._ids[k - 1] in poses and i in poses:
            self.odometry[i] = invert_T(poses[self._ids[k - 1]]) @ poses[i]

    def check_loops(
        self, loops: Mapping[Hashable, LoopConstraint], poses: Mapping[int, np.ndarray]
    ) -> list[Hashable]:
        """Handles of loops to remove after a graph update, worst first.

        ``loops``: handle -> constraint for every loop currently in the graph; ``poses``: the
        optimised ``T_world_local``. Combines the residual check
        (:func:`consistency.check_loops`) and the pairwise cycle test
        (:func:`consistency.reject_inconsistent`) over the adjacency links this detector saw.
        """
        if not self.cfg.enabled:
            return []
        bad = check_loops(loops, poses, self.cfg)
        rest = {h: lp for h, lp in loops.items() if h not in bad}
        bad += reject_inconsistent(rest, self.odometry, self.cfg)
        self.stats.rejected += len(bad)
        self.stats.rejected_after_optimisation += len(bad)
        return bad
