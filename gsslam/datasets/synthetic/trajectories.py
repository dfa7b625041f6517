"""Camera paths for the synthetic scenes: ``T_world_cam`` [N, 4, 4], OpenCV axes, world y down.

- ``orbit``: an arc of ``arc_deg`` around the room centre at radius 1.6 ``motion_scale``, looking
  at a point below it (``arc_deg=360``: a closed loop, the last pose is the first).
- ``sway_line``: forward along +z with a gentle sideways sway, looking ahead.
- ``outward_circle``: on a horizontal circle looking outward at the walls, for ``turns`` turns
  (more than one turn revisits the start: loop closure).
- ``wall_scan``: a sideways scan along x in front of the ``z = wall_z`` wall (never revisits).
- ``forward_motion``: sideways + forward with a slow yaw (parallax); ``pure_rotation``: no baseline.
- ``room_walk``: a hand-held walk around the centre of ``furnished_room`` (``ROOM_WALK`` below):
  three quarters of a loop looking at the walls, a stop and turn, back half a loop looking across the
  room at the far walls and the objects, a quick lower loop looking ahead, a second reversal and a slow
  end that sees the first views again; speeds 0-20 mm/frame (~11 m over 1000 frames), smooth hand
  shake drawn from ``seed``. Places are revisited from other positions and directions.

Building blocks for new paths: ``look_at(eye, target)`` and ``yaw_pose(position, yaw, pitch)``.
"""

from __future__ import annotations

import numpy as np

from gsslam.geometry import make_T, so3_exp


# room_walk waypoints: (time in [0, 1], angle on the circle / pi, yaw offset from outward (rad),
# radius m, height y m (down), pitch rad (> 0 up)); monotone cubic (PCHIP) in between, so every
# reversal of the angle is a smooth stop. Yaw offset 0 looks at the wall behind the circle, pi across
# the room, pi / 2 ahead when the angle grows.
ROOM_WALK = np.array([
    (0.00, 0.00, 0.00, 0.65, -0.15, -0.10),
    (0.10, 0.45, 0.25, 0.75, -0.25, -0.05),
    (0.20, 0.95, -0.20, 0.60, -0.10, -0.15),
    (0.30, 1.50, 0.10, 0.70, -0.20, -0.10),
    (0.33, 1.55, 1.60, 0.70, -0.20, -0.20),  # slows down and turns round
    (0.36, 1.50, 3.14, 0.70, -0.15, -0.30),  # reversal, looking across the room at the objects
    (0.46, 1.00, 3.44, 0.80, -0.30, -0.35),
    (0.56, 0.30, 2.94, 0.70, -0.10, -0.25),
    (0.60, 0.30, 1.90, 0.70, 0.00, -0.20),  # turns to look ahead
    (0.70, 0.90, 1.20, 0.85, 0.15, -0.10),  # lower (crouching), quicker
    (0.78, 1.60, 0.90, 0.60, -0.30, 0.00),
    (0.86, 2.30, 0.40, 0.70, -0.20, -0.10),  # second reversal
    (0.93, 2.20, 0.00, 0.65, -0.15, -0.10),  # slow, looking at the walls of the start again
    (1.00, 1.95, -0.20, 0.60, -0.10, -0.10),
])


def room_walk(n: int, motion_scale: float = 1.0, seed: int = 0) -> np.ndarray:
    from scipy.interpolate import PchipInterpolator

    t = _unit_steps(n)
    w = ROOM_WALK
    a, off, r, y, pitch = (PchipInterpolator(w[:, 0], w[:, c])(t) for c in range(1, 6))
    a = a * np.pi
    r = r * motion_scale
    rng = np.random.default_rng(seed)
    secs = t * (n - 1) / 30.0  # the shake's clock: 30 Hz frames
    shake = np.zeros((n, 6))
    for c, amp in enumerate((0.004, 0.004, 0.004, 0.003, 0.003, 0.002)):  # m x3, rad x3, per sinusoid
        for _ in range(3):
            f, ph = rng.uniform(0.3, 2.5), rng.uniform(0, 2 * np.pi)
            shake[:, c] += amp * np.sin(2 * np.pi * f * secs + ph)
    poses = []
    for k in range(n):
        p = np.array([r[k] * np.sin(a[k]), y[k], r[k] * np.cos(a[k])]) + shake[k, :3]
        T = yaw_pose(p, a[k] + off[k], pitch[k])
        T[:3, :3] = T[:3, :3] @ so3_exp(shake[k, 3:])
        poses.append(T)
    return np.stack(poses)


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:  # -> T_world_cam [4, 4]
    """OpenCV camera at ``eye`` looking at ``target``, world y (down) as the camera's down."""
    z = target - eye
    z = z / np.linalg.norm(z)
    x = np.cross(np.array([0.0, 1.0, 0.0]), z)
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    return make_T(np.stack([x, y, z], axis=1), eye)


def yaw_pose(position: np.ndarray, yaw: float, pitch: float = 0.0) -> np.ndarray:  # -> [4, 4]
    """Camera at ``position`` looking along ``yaw`` (about y; yaw 0 looks along +z), then ``pitch``."""
    R = so3_exp(np.array([0.0, yaw, 0.0])) @ so3_exp(np.array([pitch, 0.0, 0.0]))
    return make_T(R, position)


def _unit_steps(n: int) -> np.ndarray:  # [n] in [0, 1]
    return np.linspace(0.0, 1.0, n) if n > 1 else np.zeros(1)


def orbit(n: int, arc_deg: float = 90.0, motion_scale: float = 1.0) -> np.ndarray:
    span, radius = np.deg2rad(arc_deg), 1.6 * motion_scale
    poses = []
    for k in _unit_steps(n):
        a = span * k
        eye = np.array([radius * np.sin(a), -0.2 + 0.1 * np.sin(2 * a), -radius * np.cos(a)])
        poses.append(look_at(eye, np.array([0.0, 0.6, 0.0])))
    return np.stack(poses)


def sway_line(n: int, motion_scale: float = 1.0) -> np.ndarray:
    s = motion_scale
    poses = []
    for k in _unit_steps(n):
        eye = np.array([0.3 * s * np.sin(2 * np.pi * k), -0.1, -2.0 * s + 2.5 * s * k])
        poses.append(look_at(eye, eye + np.array([0.15 * np.sin(np.pi * k), 0.05, 1.0])))
    return np.stack(poses)


def outward_circle(
    n: int,
    turns: float,
    radius: float = 1.2,
    yaw_offset: float = 0.0,
    bob: float = 0.1,
    start: float = 0.0,
) -> np.ndarray:
    """Angle ``a`` from ``start`` over ``turns`` turns (negative: the other way round); position
    ``(r sin a, bob sin 3a, r cos a)``, looking outward (yaw ``a + yaw_offset``)."""
    th = start + np.linspace(0.0, 2 * np.pi * turns, n)
    return np.stack(
        [
            yaw_pose(np.array([radius * np.sin(a), bob * np.sin(3 * a), radius * np.cos(a)]), a + yaw_offset)
            for a in th
        ]
    )


def wall_scan(n: int, length: float, depth_to_wall: float, wall_z: float) -> np.ndarray:
    xs = np.linspace(-0.5 * length, 0.5 * length, n)
    return np.stack([yaw_pose(np.array([x, 0.0, wall_z - depth_to_wall]), 0.0) for x in xs])


def forward_motion(n: int, step: float = 0.06, yaw_deg: float = 1.0) -> np.ndarray:
    return np.stack(
        [
            make_T(
                so3_exp(np.array([0.0, np.radians(yaw_deg) * i, 0.0])),
                np.array([step * i, 0.02 * i, 0.5 * step * i]),
            )
            for i in range(n)
        ]
    )


def pure_rotation(n: int, deg: float = 1.5) -> np.ndarray:
    return np.stack(
        [make_T(so3_exp(np.array([0.2, 1.0, 0.0]) * np.radians(deg) * i), np.zeros(3)) for i in range(n)]
    )
