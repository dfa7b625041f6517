"""The SLAM graph: SING3R submap chain + GaussianFlow flow factors + loops + mapper depth priors.

Variables: one ``gtsam.Similarity3`` per submap, ``S(i) = T_world_local_i``. A keyframe's pose is
``T_world_cam = S(i) @ T_local_cam`` with the rigid local pose from the encoder.

Per new submap i (its frame 0 is frame K of submap i-1, ``T_local_cam[0] = I``):

- a rigid alignment ``S(i-1)^-1 S(i) ~ T_local(i-1, K)`` (:mod:`gsslam.factors.submap_alignment`),
- a scale factor ``s_i = median D(i-1, K) / median D(i, 0)`` (:mod:`gsslam.factors.scale`),
- adjacency points of the shared frame ``S(i-1)(X(i-1, K)) - S(i)(X(i, 0))`` (:mod:`gsslam.factors.points`).

Gauge: the first submap gets a Sim(3) prior fixing pose AND scale. With ``monocular=False`` (RGB-D,
metric point maps) every submap also gets a strong prior keeping its scale at 1.

Shared frames: a keyframe belongs to the FIRST submap that contains it (for a shared frame: submap
i-1, as its frame K). Flow depths are taken to be in that submap's units unless ``src_submap`` says
otherwise; keyframe poses are read through that submap.
"""

from __future__ import annotations

import logging

import numpy as np

from gsslam.config import GraphConfig
from gsslam.errors import GsslamError
from gsslam.factors import median_depth_ratio, to_gtsam, to_matrix
from gsslam.graph import stretch
from gsslam.graph.backend import Backend
from gsslam.graph.factor_specs import build_factor, spec
from gsslam.graph.keys import submap_key
from gsslam.graph.noise import flow_kwargs, gauge_prior_sigmas
from gsslam.types import Correspondences, SubmapEncoding

log = logging.getLogger(__name__)


class GraphError(GsslamError):
    """The SLAM graph was given inconsistent submaps, unknown frames or unusable measurements."""


def _even_subsample(idx: np.ndarray, n: int) -> np.ndarray:
    if len(idx) <= n:
        return idx
    return idx[np.linspace(0, len(idx) - 1, n).round().astype(int)]


class SubmapGraph:
    """Factor graph over Sim(3) submap transforms, solved incrementally by :class:`Backend` (iSAM2)."""

    def __init__(self, cfg: GraphConfig, monocular: bool):
        self.cfg = cfg
        self.monocular = monocular
        self.backend = Backend.from_config(cfg)
        self._subs: list[SubmapEncoding] = []
        self._owner: dict[int, tuple[int, int]] = {}  # frame index -> (submap, position in it)
        self.gauge_handle: int | None = None  # handle of the Sim(3) prior on s0
        # mono: a log-stretch per submap on its local translations (gsslam.graph.stretch)
        self.stretch = monocular and cfg.mono_translation_stretch

    # -- submaps -----------------------------------------------------------------------------
    def add_submap(self, enc: SubmapEncoding) -> int:
        """Add submap ``S(i)`` chained to the previous one; returns ``i``."""
        i = len(self._subs)
        if len(enc.frame_indices) < 2:
            raise GraphError(f"submap {i} needs at least 2 keyframes, got {len(enc.frame_indices)}")
        if not np.allclose(enc.T_local_cam[0], np.eye(4), atol=1e-6):
            raise GraphError(
                f"submap {i}: T_local_cam[0] must be the identity (frame 0 defines the local frame)"
            )
        key = submap_key(i)
        if i == 0:
            self.backend.add_value(key, to_gtsam(np.eye(4), "sim3"))
            self.gauge_handle = self._add(spec("sim3_prior", key, gauge_prior_sigmas(self.cfg)), "gauge prior s0")
            # an IMU replaces it by a gravity-aligned gauge (gsslam.slam.imu_stage)
        else:
            prev = self._subs[-1]
            if enc.frame_indices[0] != prev.frame_indices[-1]:
                raise GraphError(
                    f"submap {i} starts at frame {enc.frame_indices[0]} but submap {i - 1} ends at frame "
                    f"{prev.frame_indices[-1]}; consecutive submaps must share that keyframe"
                )
            self._chain(i, prev, enc)
        if self.stretch:
            self.backend.add_value(stretch.stretch_key(i), stretch.initial_value())
            self._add(stretch.prior_spec(i, self.cfg.mono_stretch_sigma), f"stretch prior t{i}")
        self._subs.append(enc)
        for j, f in enumerate(enc.frame_indices):
            self._owner.setdefault(int(f), (i, j))
        return i

    def _chain(self, i: int, prev: SubmapEncoding, enc: SubmapEncoding) -> None:
        cfg = self.cfg
        a, b = submap_key(i - 1), submap_key(i)
        try:
            ratio = median_depth_ratio(prev.depths[-1], enc.depths[0])
        except ValueError as e:
            raise GraphError(f"submap {i}: {e}") from e
        if self.monocular and enc.meta.get("world_depth"):
            # the previous submap's depth of the shared frame was exhausted (a turn); the encoder was handed
            # the chain's earlier depths rendered there in the previous submap's units instead, and frame 0
            # speaks them: the units are the previous submap's (gsslam/slam/world_depth.py)
            ratio = 1.0
        Z = prev.T_local_cam[-1]
        E = self._stretched(i - 1, Z) @ np.diag([ratio, ratio, ratio, 1.0])
        self.backend.add_value(b, to_gtsam(self.submap_pose(i - 1) @ E, "sim3"))
        if self.stretch:
            self._add(stretch.alignment_spec(i, Z, cfg.align_rot_sigma, cfg.align_trans_sigma))
        else:
            self._add(spec("submap_alignment", a, b, Z, cfg.align_rot_sigma, cfg.align_trans_sigma))
        sigma_s = cfg.scale_sigma
        if self.monocular and enc.meta.get("shared_placeholder") and cfg.mono_placeholder_scale_sigma > 0:
            sigma_s = cfg.mono_placeholder_scale_sigma  # the encoder guessed it (a turn): loops may set it
        self._add(spec("scale", a, b, float(np.log(ratio)), sigma_s))
        if prev.points_cam.shape[1:3] == enc.points_cam.shape[1:3]:
            Xa = prev.points_cam[-1].reshape(-1, 3)
            Xb = enc.points_cam[0].reshape(-1, 3)
            ok = np.isfinite(Xa).all(1) & np.isfinite(Xb).all(1)
            ok &= (prev.confidence[-1].ravel() > 0) & (enc.confidence[0].ravel() > 0)
            idx = _even_subsample(np.flatnonzero(ok), cfg.adjacency_max_points)
            if len(idx) >= 3:
                Xa_local = Xa[idx] @ Z[:3, :3].T + Z[:3, 3]
                # adjacency_sigma_m is the std of the pair's aggregate (mean) misalignment: the N points
                # of one shared frame are not N independent measurements of the submap transform (they
                # come from the same local poses), so each point gets sigma * sqrt(N). Per-point sigmas
                # made the chain so stiff that loops could not bend it (see docs/graph.md).
                sigma = cfg.adjacency_sigma_m * np.sqrt(len(idx))
                if self.stretch:
                    self._add(stretch.adjacency_spec(i, Xa[idx], Z, Xb[idx], float(sigma)))
                else:
                    self._add(spec("point", a, b, Xa_local, Xb[idx], float(sigma)))
        else:
            log.warning("submap %d: point maps of the shared frame differ in size; no adjacency points", i)
        if not self.monocular:
            self._add(spec("scale_prior", b, 1.0, cfg.prior_scale_sigma))

    # -- measurements ------------------------------------------------------------------------
    def owner(self, frame_index: int) -> tuple[int, int]:
        """``(submap, position)`` a keyframe belongs to (the first submap containing it)."""
        try:
            return self._owner[int(frame_index)]
        except KeyError:
            raise GraphError(f"frame {frame_index} is not a keyframe of any submap added so far") from None

    def _locate(self, frame_index: int, submap: int | None) -> tuple[int, int]:
        if submap is None:
            return self.owner(frame_index)
        if not 0 <= submap < len(self._subs) or frame_index not in self._subs[submap].frame_indices:
            raise GraphError(f"frame {frame_index} is not in submap {submap}")
        return submap, list(self._subs[submap].frame_indices).index(frame_index)

    def add_flow(self, corr: Correspondences, K: np.ndarray, src_submap: int | None = None) -> int | None:
        """Flow factor between the submaps of two keyframes; None for pairs inside one submap.

        ``K`` [3, 3]: intrinsics of the full-resolution images ``corr`` is in. Depths are in the
        units of ``src_submap`` (default: the submap that owns the source frame, see module doc).
        Matches with NaN / non-positive depth or zero weight are dropped; None if fewer than 3 remain.
        """
        ia, ja = self._locate(corr.src_index, src_submap)
        ib, jb = self.owner(corr.tgt_index)
        if ia == ib:
            return None
        d = corr.depth_src
        ok = np.isfinite(d) & (d > 0) & np.isfinite(corr.uv_src).all(1) & np.isfinite(corr.uv_tgt).all(1)
        ok &= np.isfinite(corr.weight) & (corr.weight > 0)
        idx = _even_subsample(np.flatnonzero(ok), self.cfg.flow_max_points)
        if len(idx) < 3:
            log.debug("flow %d->%d: %d usable matches, no factor", corr.src_index, corr.tgt_index, len(idx))
            return None
        weight = np.clip(corr.weight[idx], 0.0, 1.0)
        if self.cfg.flow_effective_points > 0:
            # The N matches of one keyframe pair are not N independent measurements of the pair's
            # relative pose (they share the flow field and the local poses); as for the adjacency
            # points, the factor gets the information of flow_effective_points matches, so that a
            # chain of flow factors stays as compliant as its real error and a loop can bend it.
            weight = weight * min(1.0, self.cfg.flow_effective_points / len(idx))
        L_a, L_b = self._subs[ia].T_local_cam[ja], self._subs[ib].T_local_cam[jb]
        if self.stretch and self.cfg.mono_stretch_flow:
            return self._add(stretch.flow_spec(ia, ib, corr.uv_src[idx], d[idx], corr.uv_tgt[idx], K, weight,
                                               L_a, L_b, flow_kwargs(self.cfg)))  # fmt: skip
        return self._add(spec(
            "flow", submap_key(ia), submap_key(ib), corr.uv_src[idx], d[idx], corr.uv_tgt[idx], K,
            weight=weight, group="sim3",
            L_a=self._subs[ia].T_local_cam[ja], L_b=self._subs[ib].T_local_cam[jb], **flow_kwargs(self.cfg),
        ))  # fmt: skip

    def add_registration(
        self, submap: int, positions: list[int], T_chain_cam: np.ndarray, information: np.ndarray
    ) -> int:
        """Keyframe poses registered against the map (rigid ``T_chain_cam`` [N, 4, 4], chain units,
        ``information`` [N, 6, 6] over (phi, rho)) as one factor on the submap's variable."""
        if not 0 <= submap < len(self._subs):
            raise GraphError(f"registration names submap {submap} but only {len(self._subs)} submaps exist")
        L = np.array(self._subs[submap].T_local_cam, dtype=np.float64)[list(positions)]
        U, _, Vt = np.linalg.svd(L[:, :3, :3])
        L[:, :3, :3] = U @ Vt
        try:
            return self._add(spec("registration", submap_key(submap), L, T_chain_cam, information, "sim3"))
        except ValueError as e:
            raise GraphError(f"registration on submap {submap}: {e}") from e

    def add_relative_registration(
        self, owner: int, submap: int, positions: list[int], T_owner_cam: np.ndarray, information: np.ndarray
    ) -> int:
        """Keyframe poses registered against the map of submap ``owner`` (rigid ``T_owner_cam`` [N, 4, 4] in
        the owner's frame and units, ``information`` [N, 6, 6] over (phi, rho)) as one factor on the
        owner's and the submap's variables: it moves with the owner
        (:mod:`gsslam.factors.relative_registration`)."""
        for s in (owner, submap):
            if not 0 <= s < len(self._subs):
                raise GraphError(f"registration names submap {s} but only {len(self._subs)} submaps exist")
        L = np.array(self._subs[submap].T_local_cam, dtype=np.float64)[list(positions)]
        U, _, Vt = np.linalg.svd(L[:, :3, :3])
        L[:, :3, :3] = U @ Vt
        try:
            return self._add(spec("relative_registration", submap_key(owner), submap_key(submap), L,
                                  T_owner_cam, information, "sim3"))  # fmt: skip
        except ValueError as e:
            raise GraphError(f"registration of submap {submap} against {owner}: {e}") from e

    def add_loop(
        self,
        i: int,
        m: int,
        X_i: np.ndarray,
        X_m: np.ndarray,
        sigma: float | None = None,
        local_units: bool = False,
        sigma_perp: float | None = None,
        dcs_phi: float = 0.0,
        views: tuple | None = None,
    ) -> int:
        """Loop points: ``S(i)(X_i) ~ S(m)(X_m)``; ``X_i``, ``X_m`` [N, 3] in the submaps' local frames.

        ``sigma``: per point, world units (default ``loop_sigma_m``); with ``local_units`` (mono) the
        residual and ``sigma`` are in submap i's units (:mod:`gsslam.factors.loop_points`), so the loop
        cannot be met by shrinking the chain's scale. With ``local_units`` and ``sigma_perp``, ``sigma``
        is along each point's viewing ray and ``sigma_perp`` across it, with a DCS kernel when
        ``dcs_phi > 0`` (:mod:`gsslam.factors.loop_rays`). ``views``: ([N], [N]) the keyframe of each
        point in submaps i and m; with the translation stretch they put the loop on both stretches."""
        for s in (i, m):
            if not 0 <= s < len(self._subs):
                raise GraphError(f"loop names submap {s} but only {len(self._subs)} submaps exist")
        if i == m:
            raise GraphError("a loop needs two different submaps")
        sig = self.cfg.loop_sigma_m if sigma is None else sigma
        try:
            with_views = self.stretch and views is not None and views[0] is not None
            if local_units and sigma_perp is not None and with_views:
                o_i = self._subs[i].T_local_cam[views[0], :3, 3]  # [N, 3] the camera that saw each point
                o_m = self._subs[m].T_local_cam[views[1], :3, 3]
                return self._add(stretch.ray_spec(i, m, X_i, o_i, X_m, o_m, sig, sigma_perp, dcs_phi))
            if local_units and sigma_perp is not None:
                ki, km = submap_key(i), submap_key(m)
                return self._add(spec("ray_point", ki, km, X_i, X_m, sig, sigma_perp, dcs_phi=dcs_phi))
            if local_units:
                return self._add(spec("relative_point", submap_key(i), submap_key(m), X_i, X_m, sig))
            return self._add(spec("point", submap_key(i), submap_key(m), X_i, X_m, sig))
        except ValueError as e:
            raise GraphError(f"loop {i}-{m}: {e}") from e

    def add_loop_pose(self, i: int, m: int, T_i_m: np.ndarray, information: np.ndarray, huber: float = 0.0) -> int:
        """Loop as a relative pose: ``S(i)^-1 S(m) ~ T_i_m`` (rigid, metres) with a 6x6 ``information``
        over its right perturbation (rotation, translation), under a Huber kernel ``huber`` (RGB-D ICP
        loops, :mod:`gsslam.loop.icp_loop`; :mod:`gsslam.factors.relative_pose`)."""
        for s in (i, m):
            if not 0 <= s < len(self._subs):
                raise GraphError(f"loop names submap {s} but only {len(self._subs)} submaps exist")
        if i == m:
            raise GraphError("a loop needs two different submaps")
        try:
            return self._add(spec("relative_pose", submap_key(i), submap_key(m), np.asarray(T_i_m, float),
                                  np.asarray(information, float), float(huber), "sim3"))  # fmt: skip
        except ValueError as e:
            raise GraphError(f"loop {i}-{m}: {e}") from e

    def add_depth_prior(
        self, frame_index: int, uv: np.ndarray, depth: np.ndarray, K: np.ndarray
    ) -> int | None:
        """Rendered depths (world units) at full-resolution pixels ``uv`` [N, 2] of a keyframe.

        The keyframe's local depths are read from its submap's point map at the nearest pixel.
        Returns None when fewer than 3 pixels have both depths.
        """
        i, j = self.owner(frame_index)
        enc = self._subs[i]
        uv, depth, K = np.asarray(uv, float), np.asarray(depth, float), np.asarray(K, float)
        if uv.ndim != 2 or uv.shape[1] != 2 or depth.shape != (len(uv),):
            raise GraphError(f"depth prior needs uv [N, 2] and depth [N], got {uv.shape} and {depth.shape}")
        Ke = enc.intrinsics
        u = np.rint((uv[:, 0] - K[0, 2]) * Ke.fx / K[0, 0] + Ke.cx).astype(int)
        v = np.rint((uv[:, 1] - K[1, 2]) * Ke.fy / K[1, 1] + Ke.cy).astype(int)
        h, w = enc.points_cam.shape[1:3]
        inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        z = np.full(len(uv), np.nan)
        z[inside] = enc.points_cam[j, v[inside], u[inside], 2]
        ok = np.isfinite(z) & (z > 0) & np.isfinite(depth) & (depth > 0)
        if ok.sum() < 3:
            return None
        return self._add(spec("depth_prior", submap_key(i), z[ok], depth[ok], self.cfg.depth_prior_sigma))

    def keyframe_anchor(self, frame_index: int) -> tuple[int, np.ndarray]:
        """``(key, T_local_cam)``: the submap variable a keyframe's pose is expressed on, and its fixed
        local pose [4, 4] (rigid, submap units): ``T_world_cam = rigid(S(key) T_local_cam)``."""
        i, j = self.owner(frame_index)
        return submap_key(i), self._subs[i].T_local_cam[j].copy()

    def add_keyframe_pose_prior(
        self,
        frame_index: int,
        T_world_cam: np.ndarray,  # [4, 4] rigid, in this graph's world
        rot_sigma: float,
        trans_sigma: float,
        name: str | None = None,
    ) -> int:
        """A prior on a keyframe's pose, mapped onto its submap's variable.

        See :mod:`gsslam.factors.keyframe_pose`; ``name`` appears in the backend's messages.
        """
        key, L = self.keyframe_anchor(frame_index)
        name = name or f"keyframe pose prior x{frame_index}"
        try:
            return self._add(spec("keyframe_pose", key, L, T_world_cam, rot_sigma, trans_sigma, "sim3"), name)
        except ValueError as e:
            raise GraphError(f"keyframe {frame_index} pose prior: {e}") from e

    def _add(self, s, name: str | None = None) -> int:
        """Build the factor of spec ``s`` and buffer it with its spec (a checkpoint can rebuild it)."""
        return self.backend.add_factor(build_factor(s), name, spec=s)

    def remove_factor(self, handle: int) -> None:
        self.backend.remove_factors([handle])

    # -- solving and reading -----------------------------------------------------------------
    def update(self, extra_iterations: int = 0) -> None:
        self.backend.update(extra_iterations)

    def refine_batch(self) -> float:
        return self.backend.refine_batch()

    @property
    def num_submaps(self) -> int:
        return len(self._subs)

    def submap_pose(self, i: int) -> np.ndarray:
        """``S(i)`` as a 4x4 Sim(3) ``[[s R, t], [0, 1]]``."""
        return to_matrix(self.backend.estimate(submap_key(i)))

    def submap_scales(self) -> np.ndarray:  # [num_submaps]
        vals = self.backend.values()
        return np.array([vals.atSimilarity3(submap_key(i)).scale() for i in range(len(self._subs))])

    def keyframe_pose(self, frame_index: int) -> np.ndarray:
        """Rigid ``T_world_cam`` [4, 4] (scale removed from the rotation; translation in world units)."""
        i, j = self.owner(frame_index)
        return self._rigid(self.submap_pose(i) @ self._stretched(i, self._subs[i].T_local_cam[j]))

    def keyframe_poses(self) -> dict[int, np.ndarray]:
        vals = self.backend.values()
        S = [to_matrix(vals.atSimilarity3(submap_key(i))) for i in range(len(self._subs))]
        return {
            f: self._rigid(S[i] @ stretch.local_pose(vals, i, self._subs[i].T_local_cam[j]))
            for f, (i, j) in sorted(self._owner.items())
        }

    def _stretched(self, i: int, L: np.ndarray) -> np.ndarray:
        """Submap i's local pose ``L`` [4, 4] with its translation stretch (as is without the option)."""
        return stretch.local_pose(self.backend.values(), i, L) if self.stretch else L

    def submap_stretches(self) -> np.ndarray:  # [num_submaps] log-stretch (zeros without the option)
        vals = self.backend.values()
        return np.array([stretch.stretch_of(vals, i) for i in range(len(self._subs))])

    @staticmethod
    def _rigid(T: np.ndarray) -> np.ndarray:
        s = np.cbrt(np.linalg.det(T[:3, :3]))
        out = T.copy()
        out[:3, :3] /= s
        return out
