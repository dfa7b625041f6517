"""Corrections inside submaps: a final batch over one pose variable per keyframe (``graph.keyframe_refine``).

The SLAM graph's variables are the submaps (:mod:`gsslam.graph.submap_graph`): a keyframe's pose is its
submap's pose composed with the encoder's fixed local pose, so neither a loop nor the final batch can
correct an error *inside* a submap. This stage runs once per chain after the final batch refinement:

- the submap graph itself on rigid submap variables ``s{i}`` (``Pose3``): submap alignment, adjacency
  points and flow factors unchanged (the same batched factors, ``group="pose3"``; RGB-D submaps are
  metric, so the scale factors are dropped), started at the graph's estimate;
- one ``Pose3`` variable ``x{f}`` per keyframe, tied to the submap that owns it (its first) by a
  ``BetweenFactorPose3`` ``s{i}^-1 x{f} ~ L_j`` (the encoder's local pose) with sigmas
  ``graph.keyframe_refine_rot_sigma`` (rad) and ``graph.keyframe_refine_trans_sigma`` (m): a
  per-keyframe correction with a prior, independent per keyframe. Without loops the optimum is the
  submap graph's (every tie at zero);
- loops move from the submaps to the keyframes they were measured between: each point of a point loop
  goes to the keyframe whose point map holds it (the view whose depth at the point's pixel is closest;
  one batched point factor per keyframe pair), an ICP relative-pose loop to the closest keyframe pair
  (the pair :mod:`gsslam.loop.icp_loop` measured; its information carried over by the adjoint);
  keyframe pose priors (plugins) and map registrations go to their keyframes (a relative one keeps its
  owner submap); the gauge prior to ``s0``.

Measured variants (docs/results.md, "Corrections inside submaps, session 7"): a chain of consecutive
keyframe pairs instead of ties lets errors walk; flow factors on the keyframe variables (instead of the
submaps) made loops-off runs worse.

Batch Levenberg-Marquardt (no iSAM2: it runs once). RGB-D only: a mono chain's keyframe translations
are in per-submap units (the stage is skipped there, logged). Kinds it cannot move (depth priors) are
left out and counted. With the map on, the map keeps the submap graph's poses.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import gtsam
import numpy as np

from gsslam.errors import GsslamError
from gsslam.factors import (
    make_keyframe_pose_factor,
    make_point_factor,
    make_registration_factor,
    make_relative_pose_factor,
    make_relative_registration_factor,
)
from gsslam.geometry import invert_T, umeyama
from gsslam.graph.factor_specs import MAKERS
from gsslam.graph.keys import keyframe_key, submap_key
from gsslam.loop.icp_loop import adjoint, closest_views
from gsslam.slam.chains import Event

log = logging.getLogger(__name__)

IMPLIED = ("scale", "scale_prior")  # RGB-D submaps are metric: rigid variables
SUBMAP_LEVEL = ("flow", "submap_alignment")  # kept on the (rigid) submap variables


@dataclass(frozen=True)
class RefineSettings:
    rot_sigma: float  # rad, a keyframe's tie to its submap
    trans_sigma: float  # m
    gauge_rot_sigma: float = 1e-4
    gauge_trans_sigma: float = 1e-4
    max_iterations: int = 100


@dataclass
class RefineResult:
    poses: dict[int, np.ndarray]  # frame -> rigid T_chain_cam [4, 4]
    error_before: float
    error_after: float
    moved: dict[str, int] = field(default_factory=dict)  # factor kind -> factors moved to keyframes
    left_out: dict[str, int] = field(default_factory=dict)  # factor kind -> factors not moved


def _rigid(T: np.ndarray) -> np.ndarray:
    out = np.array(T, dtype=np.float64)
    U, _, Vt = np.linalg.svd(out[:3, :3])
    out[:3, :3] = U @ Vt
    return out


def _submap_index(key: int) -> int:
    return int(gtsam.Symbol(int(key)).index())


class SubmapFrames:
    """Frame indices and local poses of every submap; which keyframe a local pose ``L`` names."""

    def __init__(self, frame_indices: list[list[int]], T_local_cam: list[np.ndarray], depths=None, Ks=None):
        self.frames = [list(map(int, fi)) for fi in frame_indices]
        self.L = [np.asarray(L, dtype=np.float64) for L in T_local_cam]  # [V, 4, 4] each
        self.depths = depths  # per submap [V, h, w] point-map depth (local units), or None
        self.Ks = Ks  # per submap [3, 3] intrinsics of those depths, or None

    def median_depth(self, submap: int) -> float:
        """Median point-map depth of a submap (1 without point maps), as :mod:`gsslam.loop.icp_loop` picks pairs."""
        if self.depths is None or not np.isfinite(self.depths[submap]).any():
            return 1.0
        return float(np.nanmedian(self.depths[submap]))

    def views_of(self, submap: int, X: np.ndarray) -> np.ndarray | None:  # [N, 3] local -> [N] view
        """The keyframe (position) of ``submap`` whose point map holds each local point: the view whose
        depth at the point's pixel is closest to the point's depth (None without point maps)."""
        if self.depths is None:
            return None
        D, K, L = self.depths[submap], self.Ks[submap], self.L[submap]
        V, h, w = D.shape
        Li = np.linalg.inv(L)  # [V, 4, 4]
        P = np.einsum("vij,nj->vni", Li[:, :3, :3], X) + Li[:, None, :3, 3]  # [V, N, 3]
        z = P[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.rint(K[0, 0] * P[..., 0] / z + K[0, 2])
            v = np.rint(K[1, 1] * P[..., 1] / z + K[1, 2])
        ok = (z > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        ui, vi = np.where(ok, u, 0).astype(int), np.where(ok, v, 0).astype(int)
        d = D[np.arange(V)[:, None], vi, ui]  # [V, N]
        res = np.where(ok & np.isfinite(d), np.abs(d - z), np.inf)
        return np.argmin(res, axis=0)

    def frame_of(self, submap: int, L: np.ndarray) -> int | None:
        d = np.abs(self.L[submap] - np.asarray(L)[None]).reshape(len(self.L[submap]), -1).max(1)
        j = int(np.argmin(d))
        return self.frames[submap][j] if d[j] < 1e-6 else None

    def position(self, submap: int, frame: int) -> int:
        return self.frames[submap].index(frame)

    def all_frames(self) -> list[int]:
        return sorted({f for fi in self.frames for f in fi})


def _loop_pair(fr: SubmapFrames, i: int, m: int, T_i_m: np.ndarray, depth: float) -> tuple[int, int]:
    v, u = closest_views(T_i_m, fr.L[i], fr.L[m], depth)
    return fr.frames[i][v], fr.frames[m][u]


def _move(kind: str, args: tuple, kw: dict, fr: SubmapFrames) -> gtsam.NonlinearFactor | None:
    """The factor of spec ``(kind, args, kw)`` in the keyframe graph (None: not movable)."""
    X = keyframe_key
    if kind in SUBMAP_LEVEL or (kind == "point" and _is_adjacency(args)):  # the same factor, rigid submaps
        return MAKERS[kind](*args, **{**kw, "group": "pose3"})
    if kind == "point":
        i, m = _submap_index(args[0]), _submap_index(args[1])
        X_i, X_m, sigma = np.asarray(args[2]), np.asarray(args[3]), args[4]
        T_i_m = umeyama(X_m, X_i, with_scale=False)
        depth = float(np.median(np.linalg.norm(X_i - fr.L[i][:, None, :3, 3], axis=-1)))
        vi, vm = fr.views_of(i, X_i), fr.views_of(m, X_m)
        if vi is None:  # no point maps: the loop's closest keyframe pair holds all its points
            fa, fb = _loop_pair(fr, i, m, T_i_m, depth)
            vi = np.full(len(X_i), fr.position(i, fa))
            vm = np.full(len(X_m), fr.position(m, fb))
        g = gtsam.NonlinearFactorGraph()  # one batched factor per keyframe pair the points were seen from
        for a, b in sorted(set(zip(vi.tolist(), vm.tolist()))):
            sel = (vi == a) & (vm == b)
            fa, fb = fr.frames[i][a], fr.frames[m][b]
            if sel.sum() < 3 or fa == fb:
                continue
            A, B = invert_T(fr.L[i][a]), invert_T(fr.L[m][b])
            g.add(make_point_factor(X(fa), X(fb), X_i[sel] @ A[:3, :3].T + A[:3, 3], X_m[sel] @ B[:3, :3].T + B[:3, 3],
                                    sigma, group="pose3"))  # fmt: skip
        return g if g.size() else None
    if kind == "relative_pose":
        i, m = _submap_index(args[0]), _submap_index(args[1])
        T_i_m, info, huber = np.asarray(args[2]), np.asarray(args[3]), args[4]
        fa, fb = _loop_pair(fr, i, m, T_i_m, fr.median_depth(i))  # the pair gsslam.loop.icp_loop measured
        La, Lb = _rigid(fr.L[i][fr.position(i, fa)]), _rigid(fr.L[m][fr.position(m, fb)])
        # Z' = La^-1 Z Lb; a right perturbation xi of Z is Ad(Lb^-1) xi of Z': info' = Ad(Lb)^T info Ad(Lb)
        Ad = adjoint(Lb)
        return make_relative_pose_factor(X(fa), X(fb), invert_T(La) @ T_i_m @ Lb, Ad.T @ info @ Ad, huber, "pose3")
    if kind == "keyframe_pose":
        i = _submap_index(args[0])
        f = fr.frame_of(i, args[1])
        if f is None:
            return None
        return make_keyframe_pose_factor(X(f), np.eye(4), *args[2:5], "pose3")
    if kind == "registration":
        i = _submap_index(args[0])
        Ls, T, info = np.asarray(args[1]), np.asarray(args[2]), np.asarray(args[3])
        fs = [fr.frame_of(i, L) for L in Ls]
        if any(f is None for f in fs):
            return None
        g = gtsam.NonlinearFactorGraph()  # one factor per keyframe (each has its own variable now)
        for n, f in enumerate(fs):
            g.add(make_registration_factor(X(f), np.eye(4)[None], T[n : n + 1], info[n : n + 1], "pose3"))
        return g
    if kind == "relative_registration":  # the new keyframes to their own variables, the owner stays a submap
        i = _submap_index(args[1])
        Ls, T, info = np.asarray(args[2]), np.asarray(args[3]), np.asarray(args[4])
        fs = [fr.frame_of(i, L) for L in Ls]
        if any(f is None for f in fs):
            return None
        g = gtsam.NonlinearFactorGraph()
        for n, f in enumerate(fs):
            T_n, info_n = T[n : n + 1], info[n : n + 1]
            g.add(make_relative_registration_factor(args[0], X(f), np.eye(4)[None], T_n, info_n, "pose3"))
        return g
    return None


def refine_keyframes(
    frame_indices: list[list[int]],  # per submap, its keyframes in order
    T_local_cam: list[np.ndarray],  # per submap [V, 4, 4] (metric: RGB-D)
    submap_poses: list[np.ndarray],  # per submap [4, 4] T_chain_local, the graph's estimate (scale 1)
    specs: list[tuple],  # the live factor specs of the submap graph (kind, args, kwargs)
    settings: RefineSettings,
    depths: list[np.ndarray] | None = None,  # per submap [V, h, w] point-map depth: which keyframe saw a loop point
    Ks: list[np.ndarray] | None = None,  # per submap [3, 3] intrinsics of ``depths``
) -> RefineResult:
    """Batch LM over one Pose3 per keyframe and per submap (module docstring); returns the refined
    keyframe poses (rigid ``T_chain_cam``)."""
    fr = SubmapFrames(frame_indices, T_local_cam, depths, Ks)
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([settings.rot_sigma] * 3 + [settings.trans_sigma] * 3))
    for i, (fi, L) in enumerate(zip(fr.frames, fr.L)):
        S = _rigid(submap_poses[i])
        values.insert(submap_key(i), gtsam.Pose3(S))
        for j, f in enumerate(fi):
            if values.exists(keyframe_key(f)):  # a shared frame belongs to its first submap
                continue
            values.insert(keyframe_key(f), gtsam.Pose3(_rigid(S @ L[j])))
            graph.add(gtsam.BetweenFactorPose3(submap_key(i), keyframe_key(f), gtsam.Pose3(_rigid(L[j])), noise))
    gsig = np.array([settings.gauge_rot_sigma] * 3 + [settings.gauge_trans_sigma] * 3)
    graph.add(gtsam.PriorFactorPose3(submap_key(0), gtsam.Pose3(_rigid(submap_poses[0])),
                                     gtsam.noiseModel.Diagonal.Sigmas(gsig)))  # fmt: skip
    moved: dict[str, int] = {}
    left_out: dict[str, int] = {}
    for kind, args, kw in specs:
        if kind in IMPLIED or kind == "sim3_prior":
            continue
        f = _move(kind, args, kw, fr)
        if f is None:
            left_out[kind] = left_out.get(kind, 0) + 1
            continue
        if isinstance(f, gtsam.NonlinearFactorGraph):
            graph.push_back(f)
        else:
            graph.add(f)
        moved[kind] = moved.get(kind, 0) + 1
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(settings.max_iterations)
    e0 = graph.error(values)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    e1 = graph.error(result)
    out = {f: result.atPose3(keyframe_key(f)).matrix() for f in fr.all_frames()}
    log.info("keyframe refinement: %d keyframes, error %.4g -> %.4g, moved %s, left out %s",
             len(out), e0, e1, moved, left_out)  # fmt: skip
    return RefineResult(out, e0, e1, moved, left_out)


def _is_adjacency(args: tuple) -> bool:  # add_loop(i, m) has i > m; adjacency points are (i - 1, i)
    return _submap_index(args[0]) < _submap_index(args[1])


def refine_chain(chain, settings: RefineSettings) -> RefineResult:
    """:func:`refine_keyframes` on a pipeline chain (:class:`gsslam.slam.chains.Chain`) at its graph's
    current estimate; the caller stores the poses (``chain.refined_poses``)."""
    g = chain.graph
    encs = chain.encodings
    return refine_keyframes(
        [list(e.frame_indices) for e in encs],
        [np.asarray(e.T_local_cam, dtype=np.float64) for e in encs],
        [g.submap_pose(i) for i in range(len(encs))],
        g.backend.live_specs(),
        settings,
        depths=[e.depths for e in encs],
        Ks=[e.intrinsics.K for e in encs],
    )


def settings_from(cfg) -> RefineSettings:  # cfg: gsslam.config.GraphConfig
    return RefineSettings(
        cfg.keyframe_refine_rot_sigma,
        cfg.keyframe_refine_trans_sigma,
        cfg.prior_rot_sigma,
        cfg.prior_trans_sigma,
        cfg.batch_max_iterations,
    )


def refine_chains(chains: list, cfg, monocular: bool) -> list[Event]:
    """Refine every usable chain's keyframes in place (``chain.refined_poses``); returns events for
    what could not be refined (a mono run: skipped, logged once)."""
    if monocular:
        log.info("keyframe refinement skipped: mono keyframes are in per-submap units")
        return []
    events = []
    for cid, chain in enumerate(chains):
        if not chain.encodings or chain.failed:
            continue
        try:
            chain.refined_poses = refine_chain(chain, settings_from(cfg)).poses
        except (GsslamError, RuntimeError, ValueError) as e:
            msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            events.append(Event(-1, "graph", f"keyframe refinement of chain {cid} failed: {msg}"))
            log.warning("keyframe refinement of chain %d failed: %s", cid, msg)
    return events
