"""RGB-D loops refined by dense point-to-plane ICP between two keyframes' depth maps.

A verified RGB-D loop (i, m) carries ``T_i_m`` fitted by RANSAC to a few dozen ORB point pairs; its
graph factor (``SubmapGraph.add_loop``) weighs every pair with ``graph.loop_sigma_m`` (5 cm, the inlier
distance). The depth maps of the two submaps know far more: here the closest pair of keyframes under
the loop's estimate (view ``v`` of submap i, view ``u`` of submap m) is aligned densely by
:func:`gsslam.frontend.icp.icp_point_to_plane`, started at the RANSAC estimate, and its Gauss-Newton
normal matrix becomes the information of a relative-pose factor
(:mod:`gsslam.factors.relative_pose`) on the two submap variables.

Frames: ``A = T_local_cam_i[v]``, ``B = T_local_cam_m[u]``; ICP estimates ``T = T_cv_cu`` (camera u of
m -> camera v of i) with a left perturbation ``xi = (rho, omega)`` in camera v, so
``T_i_m = A T B^-1`` and ``A Exp(xi) T B^-1 = T_i_m Exp(Ad_X xi)`` with ``X = B T^-1``: the factor's
right perturbation is ``delta = Ad_X P xi`` (``P`` puts rotation first), and the information over
``delta`` is ``(Ad_X P)^-T H (Ad_X P)^-1``.

With ``loop.icp_neighbours = n`` (RGB-D) the same factor also ties each new submap to its ``n``
predecessors (:func:`neighbour_icp`): dense depth alignment of overlapping submaps next to the flow
factors, started at the graph's estimate, whether loop closure is on or off.

A neighbour factor is measured between two keyframes and carried to the submap frames by the encoders'
local poses, whose errors ICP does not see: measured against ground truth (the two submaps at their best
rigid poses, docs/results.md "Loops that correct, session 9") the neighbour factors of the teddy rows
were off by a median 9-13 mm / 0.9-1.7 deg while their information claimed 2-3 mm / 0.1-0.2 deg. With
``loop.icp_neighbour_floor_m`` / ``loop.icp_neighbour_floor_deg`` (0: off) that floor is added to
their covariance (:func:`with_covariance_floor`).

Dense ICP residuals are not independent (neighbouring pixels share their depth error, and one pair
of keyframes shares a calibration); the Hessian of N matches is therefore rescaled to
``loop.icp_effective_points`` matches: ``Lambda = H n_eff / N``. ICP is refused (the loop keeps
its point factor) when it finds too few matches, when the normal matrix is ill-conditioned (a plane:
the translation along it is not observed) or when it moves the loop farther than
``loop.icp_max_shift_m`` / ``ICP_MAX_SHIFT_DEG`` from the RANSAC estimate.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np

from gsslam.config import LoopConfig
from gsslam.frontend.icp import icp_point_to_plane
from gsslam.geometry import invert_T, make_T, so3_exp, so3_log, split_sim3
from gsslam.loop.types import LoopConstraint
from gsslam.types import SubmapEncoding

log = logging.getLogger(__name__)

ICP_MAX_SHIFT_DEG = 5.0  # ICP refines the verified estimate; a larger turn means it slid away
LOOP_ICP_STRIDES = (4, 2)  # at point-map resolution (TUM 320x240: 80x60 then 160x120 points), as the encoder


@dataclass(frozen=True)
class IcpLoop:
    """A loop's relative pose refined by ICP: ``T_i_m`` [4, 4] (submap-m local -> submap-i local),
    ``information`` [6, 6] over its right perturbation (rotation, translation); ``views`` (v, u);
    ``inliers`` matched points; ``rmse_m`` their point-to-plane RMS; ``shift_m`` / ``shift_deg`` from
    the RANSAC estimate."""

    T_i_m: np.ndarray
    information: np.ndarray
    views: tuple[int, int]
    inliers: int
    rmse_m: float
    shift_m: float
    shift_deg: float


def closest_views(
    T_i_m: np.ndarray, L_i: np.ndarray, L_m: np.ndarray, depth_m: float, exclude: np.ndarray | None = None
) -> tuple[int, int]:
    """``(v, u)``: the keyframe of submap i and the one of submap m whose cameras are closest under
    ``T_i_m`` (``L_i`` [V, 4, 4], ``L_m`` [U, 4, 4] local camera poses); distance = translation plus
    rotation angle times the scene depth ``depth_m`` (the displacement it causes there). ``exclude``
    [V, U] bool: pairs not to pick (one frame shared by two submaps)."""
    cost = _pair_cost(T_i_m, L_i, L_m, depth_m)
    if exclude is not None:
        cost = np.where(exclude, np.inf, cost)
    v, u = np.unravel_index(int(np.argmin(cost)), cost.shape)
    return int(v), int(u)


def adjoint(T: np.ndarray) -> np.ndarray:  # [4, 4] rigid -> [6, 6] over (omega, u): Exp(Ad xi) = T Exp(xi) T^-1
    R, t = T[:3, :3], T[:3, 3]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    Ad = np.zeros((6, 6))
    Ad[:3, :3] = R
    Ad[3:, 3:] = R
    Ad[3:, :3] = tx @ R
    return Ad


def left_to_right_information(H_left: np.ndarray, T_cv_cu: np.ndarray, B: np.ndarray) -> np.ndarray:
    """ICP's normal matrix ``H_left`` [6, 6] over (rho, omega), the left perturbation of ``T_cv_cu``,
    as an information over (omega, u), the right perturbation of ``A T_cv_cu B^-1`` (module docstring)."""
    P = np.zeros((6, 6))
    P[:3, 3:] = np.eye(3)  # omega <- xi[3:]
    P[3:, :3] = np.eye(3)  # rho <- xi[:3]
    M = adjoint(B @ invert_T(T_cv_cu)) @ P  # delta = M xi
    Mi = np.linalg.inv(M)
    info = Mi.T @ H_left @ Mi
    return 0.5 * (info + info.T)


def refine_loop_icp(
    lc: LoopConstraint, enc_i: SubmapEncoding, enc_m: SubmapEncoding, cfg: LoopConfig
) -> IcpLoop | None:
    """Dense ICP of the loop's closest keyframe pair (``loop.icp_refine_pairs`` > 1: of that many
    pairs, fused by :func:`fuse_pairs`), started at ``lc.T_i_m``, its information x ``loop.icp_loop_weight``;
    None when refused."""
    icp = icp_relative_pose(lc.T_i_m, enc_i, enc_m, cfg, pairs=cfg.icp_refine_pairs)
    if icp is None:
        log.debug("loop %d-%d: ICP refused", lc.i, lc.m)
    elif cfg.icp_loop_weight != 1.0:  # loops only: the neighbour factors keep icp_effective_points' weight
        icp = replace(icp, information=icp.information * cfg.icp_loop_weight)
    return icp


def closest_pairs(
    T_i_m: np.ndarray, L_i: np.ndarray, L_m: np.ndarray, depth_m: float, exclude: np.ndarray, n: int
) -> list[tuple[int, int]]:
    """Up to ``n`` pairs ``(v, u)``, one per keyframe ``v`` of submap i with its closest keyframe ``u`` of
    submap m (the :func:`closest_views` distance), closest first; the first is :func:`closest_views`'."""
    pairs = []
    for v in range(len(L_i)):
        cost = np.where(exclude[v], np.inf, _pair_cost(T_i_m, L_i[v : v + 1], L_m, depth_m)[0])
        u = int(np.argmin(cost))
        if np.isfinite(cost[u]):
            pairs.append((float(cost[u]), v, u))
    return [(v, u) for _, v, u in sorted(pairs)[:n]]


def _pair_cost(T_i_m: np.ndarray, L_i: np.ndarray, L_m: np.ndarray, depth_m: float) -> np.ndarray:  # [V, U]
    C_m = T_i_m[None] @ L_m  # [U, 4, 4] cameras of m in i's local frame
    dt = np.linalg.norm(L_i[:, None, :3, 3] - C_m[None, :, :3, 3], axis=-1)  # [V, U]
    Rrel = np.einsum("vji,ujk->vuik", L_i[:, :3, :3], C_m[:, :3, :3])  # R_v^T R_u
    cos = np.clip((np.trace(Rrel, axis1=2, axis2=3) - 1) / 2, -1.0, 1.0)
    return dt + np.arccos(cos) * depth_m


def icp_relative_pose(
    T_i_m: np.ndarray, enc_i: SubmapEncoding, enc_m: SubmapEncoding, cfg: LoopConfig, pairs: int = 1
) -> IcpLoop | None:
    """``T_i_m`` [4, 4] (an estimate of submap m's frame in submap i's) refined by dense ICP of the two
    submaps' closest pair of distinct keyframes (a frame both submaps hold is never paired with
    itself), with its information (module docstring); None when ICP is refused. ``pairs`` > 1: the
    ``pairs`` closest pairs (one per keyframe of submap i), each aligned on its own and fused
    (:func:`fuse_pairs`); None when ICP refused them all."""
    if enc_i.points_cam.shape[1:3] != enc_m.points_cam.shape[1:3]:
        return None
    zi = enc_i.depths
    depth_m = float(np.nanmedian(zi)) if np.isfinite(zi).any() else 1.0
    same = np.asarray(enc_i.frame_indices)[:, None] == np.asarray(enc_m.frame_indices)[None, :]  # [V, U]
    if same.all():
        return None
    if pairs <= 1:
        views = [closest_views(T_i_m, enc_i.T_local_cam, enc_m.T_local_cam, depth_m, exclude=same)]
    else:
        views = closest_pairs(T_i_m, enc_i.T_local_cam, enc_m.T_local_cam, depth_m, same, pairs)
    found = [r for r in (_pair_icp(T_i_m, enc_i, enc_m, v, u, cfg) for v, u in views) if r is not None]
    if not found:
        return None
    return found[0] if len(found) == 1 else fuse_pairs(found, T_i_m)


def _pair_icp(
    T_i_m: np.ndarray, enc_i: SubmapEncoding, enc_m: SubmapEncoding, v: int, u: int, cfg: LoopConfig
) -> IcpLoop | None:
    """Keyframe ``v`` of submap i and ``u`` of submap m aligned by ICP, as a relative pose of the two
    submap frames (carried by their local poses) with its information; None when refused."""
    A, B = enc_i.T_local_cam[v], enc_m.T_local_cam[u]
    T0 = invert_T(A) @ T_i_m @ B  # camera u of m -> camera v of i
    res = icp_point_to_plane(
        enc_m.depths[u], enc_i.depths[v], enc_i.intrinsics, T0, strides=LOOP_ICP_STRIDES,
        max_step_m=cfg.icp_max_shift_m, max_step_deg=ICP_MAX_SHIFT_DEG,
    )  # fmt: skip
    if not res.ok or res.hessian is None:
        log.debug("ICP views %d/%d refused (%s, %d points)", v, u, res.reason, res.inliers)
        return None
    T_ref = A @ res.T_tgt_src @ invert_T(B)
    info = left_to_right_information(res.hessian, res.T_tgt_src, B)
    info *= cfg.icp_effective_points / max(res.inliers, 1)
    return _with_shift(IcpLoop(T_ref, info, (v, u), res.inliers, res.rmse_m, 0.0, 0.0), T_i_m)


def _with_shift(icp: IcpLoop, T_i_m: np.ndarray) -> IcpLoop:
    D = invert_T(T_i_m) @ icp.T_i_m
    shift_deg = float(np.degrees(np.linalg.norm(so3_log(D[:3, :3]))))
    return replace(icp, shift_m=float(np.linalg.norm(D[:3, 3])), shift_deg=shift_deg)


def fuse_pairs(found: list[IcpLoop], T_i_m: np.ndarray) -> IcpLoop:
    """Several keyframe pairs' ICP relative poses of one loop as one: the information-weighted mean of
    their right perturbations (rotation, translation) from the first (closest) pair's pose, with the
    MEAN of their informations (the pairs share the two submaps' local poses and depth maps: they are
    not independent measurements, so fusing them does not claim more certainty than one pair).

    Each pair carries the loop to the submap frames through its own keyframes' local poses, so the
    local poses' errors differ by pair and partly average out (docs/results.md, "RGB-D loops that
    correct, session 15": 5.5 -> 3.7 mm median loop error against ground truth)."""
    T0 = found[0].T_i_m
    H, g = np.zeros((6, 6)), np.zeros(6)
    for f in found:
        D = invert_T(T0) @ f.T_i_m  # right perturbation from T0 (small: mm, hundredths of a degree)
        d = np.concatenate([so3_log(D[:3, :3]), D[:3, 3]])
        H += f.information
        g += f.information @ d
    d = np.linalg.solve(H, g)
    T = T0 @ make_T(so3_exp(d[:3]), d[3:])
    info = H / len(found)
    rmse = float(np.sqrt(np.mean([f.rmse_m**2 for f in found])))
    out = IcpLoop(T, 0.5 * (info + info.T), found[0].views, sum(f.inliers for f in found), rmse, 0.0, 0.0)
    return _with_shift(out, T_i_m)


def with_covariance_floor(information: np.ndarray, rot_sigma_rad: float, trans_sigma_m: float) -> np.ndarray:
    """``information`` [6, 6] over (rotation, translation) with ``diag(rot^2 x3, trans^2 x3)`` added to its
    covariance: no axis is then more certain than the floor. Zero floors return it unchanged."""
    if rot_sigma_rad <= 0 and trans_sigma_m <= 0:
        return information
    floor = np.diag([rot_sigma_rad**2] * 3 + [trans_sigma_m**2] * 3)
    out = np.linalg.inv(np.linalg.inv(information) + floor)
    return 0.5 * (out + out.T)


def neighbour_icp(
    sid: int, encs: list[SubmapEncoding], poses: dict[int, np.ndarray], cfg: LoopConfig
) -> list[tuple[int, IcpLoop]]:
    """``loop.icp_neighbours``: submap ``sid`` aligned by dense ICP to each of its ``n`` predecessors,
    started at the graph's estimate (``poses``: submap -> ``T_world_local`` [4, 4] Sim(3), scale ~1 in
    RGB-D); ``(j, IcpLoop)`` for each pair ICP accepted (``T_i_m`` = submap j in submap sid's frame).
    With ``j = sid - 1`` the shared keyframe is never paired with itself. The information carries
    ``loop.icp_neighbour_floor_m`` / ``_deg`` (:func:`with_covariance_floor`)."""
    out = []
    rot_floor = float(np.radians(cfg.icp_neighbour_floor_deg))
    for j in range(max(0, sid - cfg.icp_neighbours), sid):
        R, t, _ = split_sim3(np.linalg.inv(poses[sid]) @ poses[j])
        icp = icp_relative_pose(make_T(R, t), encs[sid], encs[j], cfg)
        if icp is not None:
            info = with_covariance_floor(icp.information, rot_floor, cfg.icp_neighbour_floor_m)
            out.append((j, replace(icp, information=info)))
    return out
