"""The registration estimate's pairs re-timed for a known colour-depth delay (session 18).

The registration (:mod:`gsslam.frontend.depth_registration`: the fixed-motion fit, the hand-eye and joint
baselines) compares each pair's colour flow (colour images at ``t_a``, ``t_b``) with its depth: the points
read from depth image ``a`` and the depth camera's motion from ICP of depth images ``a`` and ``b``. With a
delay ``tau`` those depth images were taken at ``t_a + tau`` and ``t_b + tau``: every point read is
displaced by the camera's motion over the delay, and ICP measures the motion over another interval (equal to
the colour one only at constant velocity). The baseline is observed through a millimetre (a turn of
``theta`` separates the two cameras by ``theta b``), so the fit puts both into it (docs/results.md, session
17: 37.7 mm at 16 ms, 27.3 at 8 ms, 12.0 at -8 ms for 25).

:func:`retime_pairs` moves both of a pair's depth images to their colour images' times and its motion with
them::

    X(t_i) = M_i X(t_i + tau),  M_i = T_d(t_i)^-1 T_d(t_i + tau);   T_b_a(t) = M_b T_b_a(t + tau) M_a^-1

``M_i`` the depth camera's motion over the delay at frame ``i`` (:func:`frame_delay_motions`: the twist of
ICP between the raw depth images ``i-1, i`` and ``i, i+1``, each a velocity at its interval's middle,
interpolated to the middle of ``[t_i, t_i + tau]``). The images are re-projected in the depth camera's own
grid at the intrinsics the frames were given (the depth camera's where the dataset gives them, as 7-Scenes
does; where they are the colour camera's the depth camera's focal is ``k`` times longer and the move ~10 %
off, a second-order error). :func:`retime_frame` does the same for one frame (the frames the depth camera's
turn from edges reads: raw, they show the camera's turn over the delay as the depth camera's).
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from gsslam.frontend.colour_focal import FlowPair
from gsslam.frontend.depth_reprojection import reproject_depth
from gsslam.frontend.depth_retiming import depth_velocity
from gsslam.frontend.encoder import depth_edge_mask
from gsslam.geometry import invert_T, so3_exp, so3_log
from gsslam.types import CameraIntrinsics, Frame

__all__ = ["frame_delay_motions", "retime_depth", "retime_frame", "retime_pairs"]

log = logging.getLogger(__name__)

HALF_WINDOW = 1  # frame i's velocity from the consecutive intervals this many either side of it
INTERP_TOL = 0.03  # the re-projected depth read bilinearly where the 4 neighbours agree (as the run's)


def _velocity(fa: Frame, fb: Frame) -> tuple[np.ndarray, float] | None:  # (twist [6] per s, mid time)
    """The depth camera's velocity between two raw depth images (translation, rotation vector; per second,
    in frame ``a``'s depth camera) and the middle of their colour images' times; None: ICP refuses or a
    jump."""
    dt = fb.timestamp - fa.timestamp
    if fa.depth is None or fb.depth is None or not dt > 0:
        return None
    P = depth_velocity(fa.depth, fb.depth, fa.intrinsics, dt)
    if P is None:
        return None
    return np.concatenate([P[:3, 3], so3_log(P[:3, :3])]) / dt, 0.5 * (fa.timestamp + fb.timestamp)


def frame_delay_motions(
    frames: list[Frame],  # raw frames (depth in the depth camera's grid), in time order
    indices: set[int],  # the frames whose M_i is wanted
    tau: float,  # depth taken this long after colour (s)
    half: int = HALF_WINDOW,  # the velocities of the intervals (j, j + 1), j = i - half .. i + half - 1
) -> dict[int, np.ndarray]:  # index -> M_i [4, 4] (module doc); missing where no velocity is known
    """``M_i = T_d(t_i)^-1 T_d(t_i + tau)`` from the velocities of ICP with the neighbouring raw depth images,
    linear in time between them to the middle of ``[t_i, t_i + tau]`` (the one neighbour's at the ends)."""
    vel: dict[tuple[int, int], tuple[np.ndarray, float] | None] = {}

    def v(i: int, j: int):
        if (i, j) not in vel:
            vel[(i, j)] = _velocity(frames[i], frames[j]) if 0 <= i and j < len(frames) else None
        return vel[(i, j)]

    out = {}
    for i in sorted(indices):
        known = [x for x in (v(j, j + 1) for j in range(i - half, i + half)) if x is not None]
        if not known:
            continue
        t_mid = frames[i].timestamp + 0.5 * tau
        xs = np.array([x for x, _ in known])  # [n, 6]
        cs = np.array([c for _, c in known]) + tau  # [n] the depth images' intervals' middles
        if len(known) == 1 or np.ptp(cs) <= 0:
            xi = xs.mean(0)
        else:  # a straight line in time through the velocities, read at the delay's middle
            A = np.stack([np.ones_like(cs), cs - t_mid], 1)
            xi = np.linalg.lstsq(A, xs, rcond=None)[0][0]
        M = np.eye(4)
        M[:3, :3] = so3_exp(tau * xi[3:])
        M[:3, 3] = tau * xi[:3]
        out[i] = M
    return out


def retime_depth(depth: np.ndarray, intr: CameraIntrinsics, M: np.ndarray) -> np.ndarray:  # [H, W] float32
    """A depth image moved by the rigid ``M`` (points ``X -> M X``) in its own camera's grid."""
    return reproject_depth(depth, intr, intr, 0.0, 0.0, INTERP_TOL, M[:3, :3], M[:3, 3])


def retime_frame(
    before: Frame | None, frame: Frame, after: Frame | None, tau: float
) -> Frame | None:  # ``frame`` with its depth at its colour image's time; None where no velocity is known
    """One raw frame's depth moved to its colour image's time by the velocity of ICP with its neighbours'
    raw depth (:func:`frame_delay_motions`), e.g. for the depth camera's turn from edges, which otherwise
    reads the camera's turn over the delay as the depth camera's (session 18: 0.50 deg at 16 ms)."""
    if frame.depth is None:
        return None
    trio = [f for f in (before, frame, after) if f is not None]
    i = trio.index(frame)
    M = frame_delay_motions(trio, {i}, tau).get(i)
    return None if M is None else replace(frame, depth=retime_depth(frame.depth, frame.intrinsics, M))


def retime_pairs(
    pairs: list[FlowPair],
    frames: list[Frame],  # the frames the pairs were made from (index_a, index_b into these)
    tau: float,  # depth image taken this long after its colour image (s)
    motions: dict[int, np.ndarray] | None = None,  # index -> M_i; None: frame_delay_motions
) -> tuple[list[FlowPair], int]:  # the pairs at their colour images' times, how many were re-timed
    """Each pair's depth images and ICP motion moved to its colour images' times (module doc); a pair
    without both ends' ``M`` stays as it is."""
    if motions is None:
        ends = {p.index_a for p in pairs} | {p.index_b for p in pairs}
        motions = frame_delay_motions(frames, {i for i in ends if 0 <= i < len(frames)}, tau)
    out, moved = [], 0
    for p in pairs:
        Ma, Mb = motions.get(p.index_a), motions.get(p.index_b)
        if Ma is None or Mb is None:
            out.append(p)
            continue
        intr = frames[p.index_a].intrinsics
        raw_a, raw_b = retime_depth(p.raw_a, intr, Ma), retime_depth(p.raw_b, intr, Mb)
        depth_a = np.where(depth_edge_mask(raw_a), np.nan, raw_a).astype(np.float64)
        T = Mb @ p.T_b_a @ invert_T(Ma)
        out.append(replace(p, depth_a=depth_a, raw_a=raw_a, raw_b=raw_b, T_b_a=T))
        moved += 1
    return out, moved
