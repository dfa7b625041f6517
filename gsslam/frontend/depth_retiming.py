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
"""

from __future__ import annotations

import logging

import numpy as np

from gsslam.geometry import interpolate_pose, invert_T, so3_log

__all__ = ["DepthRetimer", "delay_motion", "delay_motions"]

log = logging.getLogger(__name__)

SPAN_FRAMES = 1  # the velocity over this many frames (module doc: the feedback's gain tau / (span dt))
MAX_GAP_FRAMES = 1.5  # ... each missing frame at most this many frame periods (else no velocity)
MAX_SPEED_M_S = 3.0  # a velocity above these is a jump (a new chain, a re-localisation): not used
MAX_TURN_DEG_S = 360.0


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

    def __init__(self, delay_s: float, span: int = SPAN_FRAMES) -> None:
        self.delay_s = float(delay_s)
        self.span = int(span)
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

    def motion(self, timestamp: float) -> np.ndarray | None:  # [4, 4] D_k, None: no velocity known
        """``D_k`` for the frame at ``timestamp`` at the constant velocity of the last ``span + 1`` posed frames."""
        D = self._motion(timestamp)
        if D is None:
            self.not_retimed += 1
        else:
            self.retimed += 1
        return D

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
        return {
            "delay_s": self.delay_s,
            "frames_retimed": self.retimed,
            "frames_not_retimed": self.not_retimed,
        }


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
