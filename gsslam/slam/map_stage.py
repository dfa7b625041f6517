"""The Gaussian map inside the pipeline: keyframes in after every submap, graph corrections out.

Per new submap (after the graph update and loop closure):

1. :meth:`MapStage.follow_graph` hands the current submap transforms and keyframe poses to the
   mapper (``on_poses_updated``): Gaussians of moved submaps move with them.
2. :meth:`MapStage.add_submap` adds the submap's new keyframes (Sim(3) pose ``T_world_chain S(i)
   T_local_cam``, the point map in submap units, its confidence) and the cross-submap flows that the
   pipeline computed for the graph (GaussianFlow supervision), then runs ``optimize`` on the window.
3. Feedback (SING3R: "optimized depths/poses feed back into the forming of the next submaps"; both
   switches are in the mapper config; registration (off by default since session 11) acts in mono runs (RGB-D: + ``mapper.registration_feedback_rgbd``), the depth
   paths off; docs/mapping.md):
   :meth:`MapStage.shared_depth` gives the rendered depth of the shared keyframe, in the units of the
   submap that owns it, as ``shared_depth`` for the next encoding (``mapper.shared_depth_feedback``);
   :meth:`MapStage.depth_priors` adds depths rendered at the new keyframes' graph poses (from the
   converged Gaussians of the earlier submaps, alpha > 0.99, before the keyframes add their own
   Gaussians: :mod:`gsslam.mapping.converged`) to the graph as depth-prior factors
   (``mapper.depth_feedback``); with ``mapper.registration_feedback`` the new keyframes are registered
   against that same converged map and sent as registration factors (:meth:`MapStage.send_registrations`):
   absolute priors in the chain frame, or with ``mapper.registration_relative`` relative poses to the
   submap that owns most of the converged map the keyframe was registered against (they move with loops).
   Both fire only where the converged Gaussians explain the view: on a revisit.

Submap ids are per chain in the graphs; the mapper gets one global id per ``(chain, submap)``.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import cv2
import numpy as np

from gsslam.config import MapperConfig
from gsslam.geometry import sim3_scale, split_sim3
from gsslam.types import CameraIntrinsics, Frame, StageProgress, SubmapEncoding

if TYPE_CHECKING:
    from gsslam.mapping.registration import Registration

log = logging.getLogger(__name__)


class MapStage:
    """Owns a :class:`gsslam.mapping.mapper.GaussianMapper` and keeps it in step with the graphs."""

    def __init__(self, cfg: MapperConfig, intrinsics: CameraIntrinsics, monocular: bool = False) -> None:
        from gsslam.mapping.mapper import GaussianMapper

        self.cfg = cfg
        self.intrinsics = intrinsics
        # registration against the converged map: mono by default; RGB-D only when asked (its depth and flow
        # factors are more accurate than a 160 px map's registration: docs/mapping.md)
        self.register = cfg.registration_feedback and (monocular or cfg.registration_feedback_rgbd)
        self.mapper = GaussianMapper(cfg, intrinsics)
        self._gid: dict[tuple[int, int], int] = {}  # (chain, submap) -> mapper submap id
        self._anchor: dict[int, tuple[int, int, int]] = {}  # keyframe -> (chain, submap, position)
        self.n_depth_priors = 0
        self.n_registrations = 0  # keyframes registered against the map and sent to the graph
        self.n_registrations_gated = 0  # registered, but the map could not tell their pose
        self.n_registrations_withheld = 0  # registered, but Gauss-Newton did not reach the map's minimum
        self.withheld: list[Registration] = []  # the last call's (mapper.registration_unconverged_weight=0)
        self.pending: list[tuple[int, Registration]] = []  # (position in the new submap, registration)
        # relative ones: position -> [(owner submap, T_owner_cam rigid [4, 4] in owner units, info [6, 6])]
        self.pending_owner: dict[int, list[tuple[int, np.ndarray, np.ndarray]]] = {}
        self.n_registrations_relative = 0  # of the sent ones, relative to an owner submap
        self.owner_shares: list[float] = []  # the owners' share of the converged view, per relative one
        self.pending_depth: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # keyframe -> (uv, depth)
        self.seconds = 0.0
        self.iterations = 0
        self.final_iterations = 0
        self.window_seconds = self.final_seconds = 0.0
        self.final_stats: dict = {}
        self.last_stats: dict = {}
        self.joint_stats: dict = {}  # final joint pose+map refinement (mapper.final_pose_iterations)
        self.refined_keyframe_poses: dict[int, np.ndarray] = {}  # its keyframe T_world_cam (Sim(3))

    def global_id(self, chain: int, submap: int) -> int:
        return self._gid.setdefault((chain, submap), len(self._gid))

    # ---- poses -------------------------------------------------------------------------------

    @staticmethod
    def _submap_pose(chain, submap: int) -> np.ndarray:  # [4, 4] Sim(3) T_world_local
        return chain.T_world_chain @ chain.graph.submap_pose(submap)

    def _keyframe_pose(self, chains, index: int) -> np.ndarray:  # [4, 4] Sim(3) T_world_cam
        c, s, pos = self._anchor[index]
        chain = chains[c]
        return self._submap_pose(chain, s) @ chain.encodings[s].T_local_cam[pos]

    def follow_graph(self, chains) -> int:
        """Move the map with the graphs' current estimates; returns the number of Gaussians moved."""
        submaps = {}
        for (c, s), gid in self._gid.items():
            if s < len(chains[c].encodings):
                submaps[gid] = self._submap_pose(chains[c], s)
        kfs = {
            i: self._keyframe_pose(chains, i)
            for i, (c, s, _) in self._anchor.items()
            if s < len(chains[c].encodings)
        }
        return self.mapper.on_poses_updated(submaps, kfs)

    # ---- input -------------------------------------------------------------------------------

    def add_submap(
        self,
        chains,
        cid: int,
        sid: int,
        enc: SubmapEncoding,
        frames: list[Frame],  # the K+1 keyframes of ``enc``, in order
        new_keyframes: list[int],  # frame indices first encoded in this submap
        flows: list[tuple[int, int, np.ndarray, np.ndarray]],  # (a, b, flow [H, W, 2], valid [H, W])
    ) -> dict:
        """Add the submap's new keyframes and flows, optimise the window; returns the optimiser stats."""
        gid = self.global_id(cid, sid)
        self.follow_graph(chains)  # records the new submap's transform before its Gaussians exist
        by_index = {f.index: f for f in frames}
        self.pending = []
        self.pending_owner = {}
        self.pending_depth = {}
        if self.cfg.depth_feedback and len(self.mapper.model):
            # rendered before the keyframes seed their own Gaussians: the depth is the earlier submaps'
            # evidence, not the keyframe's own point map handed back (docs/results.md, "Feedback")
            # and only the converged Gaussians' (mapper.feedback_min_age): loop-like evidence on a revisit
            from gsslam.mapping.converged import converged_depth

            for idx in new_keyframes:
                pos = list(enc.frame_indices).index(idx)
                T = self._submap_pose(chains[cid], sid) @ enc.T_local_cam[pos]
                uv, depth, _ = converged_depth(self.mapper.map, T, self.cfg.depth_feedback_points)
                self.pending_depth[idx] = (self.mapper.full_res_uv(uv), depth)
        if self.register:
            self.pending = self._register(chains, cid, sid, enc, by_index, new_keyframes)
        for idx in new_keyframes:
            pos = list(enc.frame_indices).index(idx)
            self._anchor[idx] = (cid, sid, pos)
            self.mapper.add_keyframe(
                by_index[idx],
                self._keyframe_pose(chains, idx),
                gid,
                points_cam=enc.points_cam[pos],
                confidence=enc.confidence[pos],
            )
        known = set(self.mapper.keyframe_indices)
        for a, b, flow, valid in flows:
            if a in known and b in known:
                self.mapper.add_flow(a, b, flow, valid)
        stats = self.mapper.optimize()
        self.seconds += stats.get("seconds", 0.0)
        self.iterations += stats.get("iterations", 0)
        self.last_stats = stats
        log.debug("mapper: %s", {k: v for k, v in stats.items() if not isinstance(v, dict)})
        return stats

    def finalize(self, chains, run_seconds: float = 0.0, progress: StageProgress | None = None) -> dict:
        """End of the run: follow the final graph estimates, then the global pass over all keyframes.

        ``run_seconds`` (the run's wall time so far) and the mean seconds per window step bound the pass
        when ``mapper.final_max_share`` is set; ``progress("final pass", done, total)`` after every step.
        """
        self.follow_graph(chains)
        cb = None if progress is None else (lambda done, total: progress("final pass", done, total))
        step_s = self.seconds / self.iterations if self.iterations else 0.0
        window_s = self.seconds
        stats = self.mapper.finalize(progress=cb, step_seconds=step_s, run_seconds=run_seconds)
        self.seconds += stats.get("seconds", 0.0)
        self.window_seconds = window_s
        self.final_seconds = stats.get("seconds", 0.0)
        keys = ("capped", "uncapped_iterations", "visits_min", "visits_max", "coarse", "threads")
        self.final_stats = {k: stats.get(k) for k in keys}
        self.final_iterations = stats.get("iterations", 0)
        if self.cfg.final_pose_iterations > 0:
            self.joint_stats = self.mapper.refine_joint()
            self.seconds += self.joint_stats.get("seconds", 0.0)
            self.refined_keyframe_poses = self.mapper.refined_poses()
        return stats

    # ---- feedback ----------------------------------------------------------------------------

    def shared_depth(self, chains, index: int, pointmap_depth: np.ndarray) -> np.ndarray:
        """Rendered depth of keyframe ``index`` in its owner submap's units at ``pointmap_depth``'s size.

        Only pixels where the encoder had a depth and the map is opaque (alpha > 0.99) take the rendered
        one; the others keep ``pointmap_depth`` [h, w]. Where the point map had none (mono: ~55 % of the
        shared frame on teddy), the map's Gaussians were inpainted and their depth was 68 % off (median,
        docs/results.md "Feedback"): handing it on made the next submap worse.
        """
        if index not in self._anchor:
            return pointmap_depth
        c, s, _ = self._anchor[index]
        scale = sim3_scale(self._submap_pose(chains[c], s))
        out = self.mapper.render_keyframe(index)
        h, w = pointmap_depth.shape
        r = cv2.resize(out.depth.cpu().numpy(), (w, h), interpolation=cv2.INTER_NEAREST) / scale  # submap u.
        a = cv2.resize(out.alpha.cpu().numpy(), (w, h), interpolation=cv2.INTER_NEAREST)
        take = (a > 0.99) & np.isfinite(r) & (r > 0) & np.isfinite(pointmap_depth) & (pointmap_depth > 0)
        return np.where(take, r, pointmap_depth).astype(np.float32)

    def _register(
        self, chains, cid: int, sid: int, enc: SubmapEncoding, by_index: dict, new_keyframes: list[int]
    ):
        """Register the new keyframes (at the graph's pose) against the map as it was before them."""
        out = []
        self.withheld = []
        for idx in new_keyframes:
            pos = list(enc.frame_indices).index(idx)
            T = self._submap_pose(chains[cid], sid) @ enc.T_local_cam[pos]
            reg = self.mapper.register(by_index[idx], T, enc.points_cam[pos], enc.confidence[pos])
            if reg is None:
                self.n_registrations_gated += 1
            elif reg.weight <= 0.0:  # not at the map's minimum: no evidence of where the pose is
                self.n_registrations_withheld += 1
                self.withheld.append(reg)
            else:
                out.append((pos, reg))
                if self.cfg.registration_relative:
                    self._find_owner(chains, cid, sid, pos, reg)
        return out

    def _find_owner(self, chains, cid: int, sid: int, pos: int, reg: Registration) -> None:
        """The registration relative to the submap (same chain, older) whose converged Gaussians carry most
        of the registered view's rendered weight; with ``mapper.registration_owner_split`` > 0, relative to
        every such submap with at least that share, each with its share of the information (renormalised
        over those kept). Kept in ``pending_owner`` (no owner: sent as absolute)."""
        where = {gid: cs for cs, gid in self._gid.items()}
        owners = []  # (submap, share), largest share first
        shares = self.mapper.registration_owners(reg.T_world_cam)
        for gid, share in sorted(shares.items(), key=lambda x: -x[1]):
            c, s = where.get(gid, (-1, -1))
            if c == cid and s != sid and s < len(chains[c].encodings):
                owners.append((s, share))
        if not owners:
            return
        split = self.cfg.registration_owner_split
        kept = [o for o in owners if split > 0 and o[1] >= split] or owners[:1]
        total = sum(share for _, share in kept)
        self.pending_owner[pos] = []
        for s, share in kept:
            S_wo = self._submap_pose(chains[cid], s)  # [4, 4] Sim(3) T_world_owner now (the map follows it)
            M = np.linalg.inv(S_wo) @ reg.T_world_cam  # Sim(3) with scale 1 / s_wo: the camera in owner units
            s_wo = sim3_scale(S_wo)
            M[:3, :3] *= s_wo
            D = np.diag([1.0, 1.0, 1.0] + [s_wo] * 3)  # owner translation = world translation / s_wo
            self.pending_owner[pos].append((s, M, (share / total) * D @ reg.information @ D))
        self.owner_shares.append(total)

    def send_registrations(self, chain, sid: int) -> int:
        """The pending registrations as factors on submap ``sid`` of ``chain``: one per owner submap for the
        relative ones, one absolute prior for the rest; returns how many registrations."""
        if not self.pending:
            return 0
        n = len(self.pending)
        owners: dict[int, list[tuple[int, np.ndarray, np.ndarray]]] = {}  # owner -> [(position, T, info)]
        for pos, _ in self.pending:
            for o, T, info in self.pending_owner.get(pos, []):
                owners.setdefault(o, []).append((pos, T, info))
            self.n_registrations_relative += pos in self.pending_owner
        for o, rel in owners.items():
            chain.graph.add_relative_registration(
                o, sid, [r[0] for r in rel], np.stack([r[1] for r in rel]), np.stack([r[2] for r in rel])
            )
        self.pending = [(p, r) for p, r in self.pending if p not in self.pending_owner]
        self.pending_owner = {}
        self.n_registrations += n
        if not self.pending:
            return n
        R_c, t_c, c = split_sim3(np.linalg.inv(chain.T_world_chain))  # world -> chain (scale c)
        T, info = [], []
        D = np.diag([1.0, 1.0, 1.0] + [1.0 / c] * 3)  # chain translation = c x world translation
        for _, reg in self.pending:
            M = np.eye(4)
            M[:3, :3] = R_c @ reg.T_world_cam[:3, :3]
            M[:3, 3] = c * (R_c @ reg.T_world_cam[:3, 3]) + t_c
            T.append(M)
            info.append(D @ reg.information @ D)
        chain.graph.add_registration(sid, [p for p, _ in self.pending], np.stack(T), np.stack(info))
        self.pending = []
        return n

    def depth_priors(self, graph, indices: list[int]) -> int:
        """Depths rendered for keyframes ``indices`` before they joined the map (:meth:`add_submap`,
        ``mapper.depth_feedback_points`` each) as depth-prior factors in ``graph``; returns how many."""
        added = 0
        for idx in indices:
            if idx not in self.pending_depth:
                continue
            uv, depth = self.pending_depth.pop(idx)
            if len(uv) >= 3 and graph.add_depth_prior(idx, uv, depth, self.intrinsics.K) is not None:
                added += 1
        self.n_depth_priors += added
        return added

    # ---- outputs -----------------------------------------------------------------------------

    def metrics(self) -> dict:
        return {
            "keyframes": len(self.mapper.keyframe_indices),
            "num_gaussians": self.mapper.num_gaussians,
            "size_mb": self.mapper.size_mb,
            "optimize_seconds": self.seconds,
            "iterations": self.iterations,
            "final_iterations": self.final_iterations,
            "window_seconds": self.window_seconds,
            "final_seconds": self.final_seconds,
            **{f"final_{k}": v for k, v in self.final_stats.items()},
            "final_pose_iterations": self.joint_stats.get("iterations", 0),
            "final_pose_moved_mean": self.joint_stats.get("pose_moved_mean"),
            "final_pose_moved_max": self.joint_stats.get("pose_moved_max"),
            "depth_prior_factors": self.n_depth_priors,
            "registration_factors": self.n_registrations,
            "registrations_gated": self.n_registrations_gated,
            "registrations_withheld": self.n_registrations_withheld,
            "registrations_relative": self.n_registrations_relative,
            "registration_owner_share": float(np.mean(self.owner_shares)) if self.owner_shares else None,
            "width": self.mapper.intrinsics.width,
            "height": self.mapper.intrinsics.height,
            "rasterizer_backend": self.mapper.rasterizer_backend,
        }
