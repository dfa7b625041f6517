"""Re-timing a frame's depth for a known delay between its colour and depth images (session 17).

A Kinect v1's colour and depth streams are not synchronised: frame k's depth image is taken by the depth
camera at ``t_k + tau`` while its colour image is taken at ``t_k``. A point ``X_d`` the depth camera sees is,
in the colour camera at ``t_k``,

    X_c = T_c(t_k)^-1 T_c(t_k + tau) T_colour_depth X_d = D_k T_colour_depth X_d,

``D_k`` the colour camera's own motion over the delay. :func:`register_frame
<gsslam.frontend.depth_registration.register_frame>` re-projects the depth with ``D_k T_colour_depth``
instead of the constant registration, so that the colour camera reads, at ``t_k``, the surface it saw.
``tau > 0``: depth after colour; ``tau < 0``: before.

``D_k`` comes from the colour camera's velocity at ``t_k``; at ingestion only the poses already tracked are
known, so :class:`DepthRetimer` extrapolates them at constant velocity (the same interpolation as
:func:`gsslam.geometry.interpolate_pose`: geodesic rotation, linear translation). Those poses were themselves
tracked on re-timed depth, so the velocity feeds back: with the last two poses, a pose error ``e_k`` moves
the next frame's depth by ``tau / dt (e_k - e_{k-1})`` and its pose by about as much, the other way; at
``tau`` half a frame that loop is on the edge of oscillation (measured: the predicted motion alternating
+-5 mm frame to frame at 16 ms). The velocity is therefore taken over ``span`` frames (the first and the
last of the last ``span + 1`` posed frames): the loop's gain is ``tau / (span dt)``. :func:`delay_motions` gives ``D_k`` of a finished trajectory from each frame's
two neighbours (centred): the depth camera's poses at the depth images' time (7-Scenes' ground truth) for
:mod:`gsslam.run.trajectory_camera`.

Session 18: a velocity tracking does not feed (``depth_intrinsics`` given): ICP between the previous and this
frame's raw depth images (:func:`depth_velocity`; the depth camera's motion over ``[t_{k-1} + tau, t_k +
tau]``, seen from the colour camera through ``T_colour_depth``), the tracked poses' only where ICP refuses.
Its error is each pair's own, not fed back, and it lags the delay's middle by ``(dt - tau) / 2`` instead of
``1.5 dt + tau / 2``. :meth:`DepthRetimer.prime` gives the first frames, before any velocity is known, the
velocity of ICP between the first two raw depth images (one frame read ahead): the first frame starts the map.
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from gsslam.frontend.icp import TRACK_STRIDES, icp_point_to_plane
from gsslam.geometry import interpolate_pose, invert_T, so3_log
from gsslam.types import CameraIntrinsics

__all__ = ["DepthRetimer", "delay_motion", "delay_motions", "depth_velocity"]

log = logging.getLogger(__name__)

SPAN_FRAMES = 1  # the velocity over this many frames (module doc: the feedback's gain tau / (span dt))
MAX_GAP_FRAMES = 1.5  # ... each missing frame at most this many frame periods (else no velocity)
MAX_SPEED_M_S = 3.0  # a velocity above these is a jump (a new chain, a re-localisation): not used
MAX_TURN_DEG_S = 360.0
VELOCITY_ICP_STRIDES = TRACK_STRIDES + (4,)  # raw depth images 640 px wide: 40x30 to 160x120 points


def depth_velocity(
    depth_a: np.ndarray,  # [H, W] metres, NaN invalid: the earlier raw depth image (depth camera grid)
    depth_b: np.ndarray,  # [H, W] the later one
    intr: CameraIntrinsics,  # the depth camera's
    seconds: float,  # between them (> 0)
    T_init: np.ndarray | None = None,  # [4, 4] T_b_a to start ICP from (None: identity)
    rotation_if_ill: bool = False,  # where ICP is ill-conditioned (a bare wall): its rotation, no translation
) -> np.ndarray | None:  # [4, 4] frame b's depth camera in frame a's (T_a_b); None: ICP refuses or a jump
    """The depth camera's motion between two raw depth images, by point-to-plane ICP. Ill-conditioned (the
    room's bare walls) ICP slides along the wall (measured: 18 mm median error over a 16 ms delay) but still
    turns right (0.02 deg): ``rotation_if_ill`` keeps that turn alone."""
    init = np.eye(4) if T_init is None else T_init
    scale = depth_a.shape[1] / 640.0  # the same points across at any width (320 px: strides 8, 4, 2)
    strides = tuple(max(1, round(s * scale)) for s in VELOCITY_ICP_STRIDES)
    icp = icp_point_to_plane(depth_a, depth_b, intr, init, strides=strides)
    if not icp.ok and rotation_if_ill and icp.reason == "ill_conditioned":
        icp = icp_point_to_plane(depth_a, depth_b, intr, init, strides=strides, min_condition=0.0)
        if icp.ok:
            T = np.eye(4)
            T[:3, :3] = icp.T_tgt_src[:3, :3]
            icp = replace(icp, T_tgt_src=T)
    if not icp.ok:
        return None
    P = invert_T(icp.T_tgt_src)
    return P if plausible(np.eye(4), P, seconds) else None


def delay_motion(
    T_a: np.ndarray,  # [4, 4] T_world_cam at time t_a
    t_a: float,
    T_b: np.ndarray,  # [4, 4] T_world_cam at time t_b != t_a
    t_b: float,
    t: float,  # the colour image's time
    tau: float,  # the delay (s)
) -> np.ndarray:  # [4, 4] D = T(t)^-1 T(t + tau) at the constant velocity of a -> b
    """The camera's motion from ``t`` to ``t + tau`` in its own frame, moving as from ``T_a`` to ``T_b``."""
    span = t_b - t_a
    at = interpolate_pose(T_a, T_b, (t - t_a) / span)
    later = interpolate_pose(T_a, T_b, (t + tau - t_a) / span)
    return invert_T(at) @ later


def plausible(T_a: np.ndarray, T_b: np.ndarray, seconds: float) -> bool:
    """The motion ``T_a -> T_b`` over ``seconds`` is a camera's, not a jump between chains."""
    rel = invert_T(T_a) @ T_b
    speed = np.linalg.norm(T_b[:3, 3] - T_a[:3, 3]) / seconds
    turn = np.degrees(np.linalg.norm(so3_log(rel[:3, :3]))) / seconds
    return bool(speed <= MAX_SPEED_M_S and turn <= MAX_TURN_DEG_S)


class DepthRetimer:
    """The colour camera's motion over the delay for the next frame, from the last two posed frames."""

    def __init__(
        self,
        delay_s: float,
        span: int = SPAN_FRAMES,
        depth_intrinsics: CameraIntrinsics | None = None,  # the depth camera's: ICP of raw depth possible
        T_colour_depth: np.ndarray | None = None,  # [4, 4] the registration (None: the identity)
        raw_velocity: bool = False,  # the velocity from the raw depth (module doc; needs depth_intrinsics)
    ) -> None:
        self.delay_s = float(delay_s)
        self.span = int(span)
        self.depth_intrinsics = depth_intrinsics
        self.raw_velocity = bool(raw_velocity and depth_intrinsics is not None)
        self._primed: tuple[float, float, np.ndarray] | None = None  # (t0, t1, the colour camera's motion)
        self.primed = 0  # frames re-timed by the first two raw depth images' velocity (prime)
        self.T_colour_depth = np.eye(4) if T_colour_depth is None else np.asarray(T_colour_depth, np.float64)
        self._raw: tuple[float, np.ndarray] | None = None  # the previous frame's (timestamp, raw depth)
        self._raw_T: np.ndarray | None = None  # its ICP motion T_b_a (the next ICP's start)
        self.from_depth = 0  # frames whose velocity came from the raw depth
        self._last: list[
            tuple[float, np.ndarray]
        ] = []  # at most span + 1 (timestamp, T_world_cam), older first
        self._period: float | None = None  # the smallest gap between two frames seen
        self.retimed = 0  # frames whose depth was moved by a velocity
        self.not_retimed = 0  # frames without one (the first two, after a loss or a jump)

    def observe(self, timestamp: float, T_world_cam: np.ndarray | None) -> None:
        """The pose the pipeline gave the frame at ``timestamp`` (None: not posed, the velocity is lost)."""
        if self._last:
            gap = timestamp - self._last[-1][0]
            if gap > 0:
                self._period = gap if self._period is None else min(self._period, gap)
        if T_world_cam is None:
            self._last = []
            return
        self._last = [*self._last[-self.span :], (float(timestamp), np.array(T_world_cam, dtype=np.float64))]

    def motion(
        self, timestamp: float, depth: np.ndarray | None = None  # [H, W] the frame's raw depth (depth grid)
    ) -> np.ndarray | None:  # [4, 4] D_k, None: no velocity known
        """``D_k`` for the frame at ``timestamp``: from ICP of the previous and this raw depth image where
        ``depth_intrinsics`` were given and ICP succeeds, else at the constant velocity of the last
        ``span + 1`` posed frames."""
        D = self._depth_motion(timestamp, depth) if self.raw_velocity else None
        if D is not None:
            self.from_depth += 1
        else:
            D = self._motion(timestamp)
        if D is None and self._primed is not None:
            t0, t1, Pc = self._primed
            if t0 - 1e-6 <= timestamp <= t1 + 1e-6:
                D = delay_motion(np.eye(4), t0, Pc, t1, timestamp, self.delay_s)
                self.primed += 1
        if D is None:
            self.not_retimed += 1
        else:
            self.retimed += 1
        return D

    def prime(self, t0: float, depth0: np.ndarray | None, t1: float, depth1: np.ndarray | None) -> bool:
        """The first frames' velocity (frames ``t0`` .. ``t1``, before tracking gives one) from ICP of the
        first two raw depth images (read one frame ahead; needs ``depth_intrinsics``). Without it the first
        frame, which starts the map, keeps its depth at the depth image's pose: measured on the Kinect room's
        first 40 frames at 16 ms, that alone costs 0.14 -> 0.43 cm (docs/results.md, session 18). False: no
        velocity."""
        if self.depth_intrinsics is None or depth0 is None or depth1 is None or not t1 > t0:
            return False
        P = depth_velocity(depth0, depth1, self.depth_intrinsics, t1 - t0, rotation_if_ill=True)
        if P is None:
            return False
        self._primed = (float(t0), float(t1), self._in_colour(P))
        return True

    def _in_colour(self, P: np.ndarray) -> np.ndarray:  # the depth camera's motion P as the colour camera's
        return self.T_colour_depth @ P @ invert_T(self.T_colour_depth)

    def _depth_motion(self, timestamp: float, depth: np.ndarray | None) -> np.ndarray | None:
        prev, self._raw = self._raw, (None if depth is None else (float(timestamp), depth))
        if prev is None or depth is None or not timestamp > prev[0]:
            self._raw_T = None
            return None
        if self._period is not None and timestamp - prev[0] > MAX_GAP_FRAMES * self._period:
            self._raw_T = None
            return None
        P = depth_velocity(prev[1], depth, self.depth_intrinsics, timestamp - prev[0], self._raw_T)
        self._raw_T = None if P is None else invert_T(P)
        if P is None:
            return None
        return delay_motion(np.eye(4), prev[0], self._in_colour(P), timestamp, timestamp, self.delay_s)

    def _motion(self, timestamp: float) -> np.ndarray | None:
        if len(self._last) < self.span + 1 or self._period is None:
            return None
        (ta, A), (tb, B) = self._last[0], self._last[-1]
        if not (ta < tb < timestamp) or timestamp - ta > (self.span + 1) * MAX_GAP_FRAMES * self._period:
            return None
        if not plausible(A, B, tb - ta):
            return None
        return delay_motion(A, ta, B, tb, timestamp, self.delay_s)

    def record(self) -> dict:
        """For ``metrics.json``."""
        out = {"delay_s": self.delay_s, "frames_retimed": self.retimed, "frames_not_retimed": self.not_retimed}
        if self.depth_intrinsics is not None:  # session 18: the first frames primed, the raw depth's velocity
            out["frames_primed"] = self.primed
        if self.raw_velocity:
            out.update(velocity="depth", frames_velocity_from_depth=self.from_depth)
        return out


def delay_motions(
    poses: dict[int, np.ndarray],  # frame -> T_world_cam [4, 4]
    timestamps: dict[int, float],  # frame -> its colour image's time
    tau: float,
) -> dict[int, np.ndarray]:  # frame -> D [4, 4] (identity where no neighbour gives one)
    """``D`` of every frame from the velocity between its neighbours (centred where both are posed)."""
    out = {}
    for i in poses:
        a, b = (i - 1 if i - 1 in poses else i), (i + 1 if i + 1 in poses else i)
        out[i] = np.eye(4)
        if a == b or a not in timestamps or b not in timestamps or i not in timestamps:
            continue
        span = timestamps[b] - timestamps[a]
        if span <= 0 or not plausible(poses[a], poses[b], span):
            continue
        out[i] = delay_motion(poses[a], timestamps[a], poses[b], timestamps[b], timestamps[i], tau)
    return out
