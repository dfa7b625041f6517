"""The depth camera's turn from edges (frontend/registration_edges.py) on an honestly synthetic frame:
boxes in front of a wall, the depth image ray-cast from the depth camera and the colour image from
the colour camera, turned against it by a known rotation and 25 mm to the side. The wall carries
stripes: colour edges with no depth edge, which the estimate must not follow. Measured here
(docs/results.md, "The depth camera's turn from edges, session 17"): turns of ~0.5 deg come back
within 0.04 deg about x and y and 0.11 deg about z (the optical axis), no turn as (0.02, -0.02,
0.11) deg; a bare wall has no contours and is not observed."""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.frontend.depth_registration import DepthRegistration, edge_turn_correction
from gsslam.frontend.registration_edges import depth_edges, estimate_turn
from gsslam.frontend.registration_record import registration_record
from gsslam.geometry import so3_exp
from gsslam.types import CameraIntrinsics, Frame

W, H = 320, 240
DEPTH = CameraIntrinsics(285.0, 285.0, 159.5, 119.5, W, H)
COLOUR = DEPTH.with_focal(1.0 / 1.114)
BASELINE_M = 0.025
WALL_Z = 3.0
BOXES = [  # x0, x1, y0, y1, z, grey (fronto-parallel rectangles in the depth camera frame)
    (-0.9, -0.3, -0.6, -0.1, 1.6, 0.85),
    (0.2, 0.8, -0.5, 0.05, 1.4, 0.15),
    (-0.7, -0.1, 0.2, 0.7, 1.8, 0.7),
    (0.3, 0.9, 0.25, 0.75, 1.5, 0.3),
]


def _cast(intr: CameraIntrinsics, R: np.ndarray, c: np.ndarray, boxes) -> tuple[np.ndarray, np.ndarray]:
    """Depth (the camera's z) and grey of the scene seen from centre ``c``, turned by ``R`` (depth frame)."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    rays = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u)], -1)  # camera frame
    d = rays @ R.T  # [H, W, 3] in the depth frame
    s = (WALL_Z - c[2]) / d[..., 2]
    p = c + s[..., None] * d
    grey = 0.5 + 0.2 * np.sign(np.sin(p[..., 0] * 9.0))  # the wall's stripes: colour edges only
    for x0, x1, y0, y1, z, g in boxes:
        sb = (z - c[2]) / d[..., 2]
        q = c + sb[..., None] * d
        hit = (q[..., 0] > x0) & (q[..., 0] < x1) & (q[..., 1] > y0) & (q[..., 1] < y1) & (sb < s)
        s = np.where(hit, sb, s)
        grey = np.where(hit, g, grey)
    return s.astype(np.float32), grey  # the point is s * ray in the camera, whose z is 1: s is its depth


def _frame(rotation_deg, boxes=BOXES) -> Frame:
    R_cd = so3_exp(np.radians(np.asarray(rotation_deg, dtype=np.float64)))  # R_colour_depth
    depth, _ = _cast(DEPTH, np.eye(3), np.zeros(3), boxes)
    # the colour camera in the depth frame: X_colour = R_cd X_depth + t, t = (b, 0, 0)
    c = -R_cd.T @ np.array([BASELINE_M, 0.0, 0.0])
    _, grey = _cast(COLOUR, R_cd.T, c, boxes)
    image = np.repeat(grey[..., None], 3, axis=2).astype(np.float32)
    return Frame(0, 0.0, image, DEPTH, depth=depth)


def test_depth_edges_middle_of_a_gap():
    depth = np.full((4, 12), 3.0, np.float32)
    depth[:, :5] = 1.5
    depth[:, 5:7] = np.nan  # a two-pixel shadow between the near and far sides
    u, v, z, along_u, far = depth_edges(depth)
    assert along_u.all() and len(u) == 4
    np.testing.assert_allclose(u, 5.5)  # between pixel 4 (near) and pixel 7 (far)
    np.testing.assert_allclose(z, 1.5)
    np.testing.assert_allclose(far, 1.0)


@pytest.mark.parametrize("turn", [(0.5, -0.4, -0.15), (-0.3, 0.6, 0.3), (0.0, 0.0, 0.0)])
def test_turn_recovered(turn):
    est = estimate_turn([_frame(turn)], DEPTH, COLOUR, BASELINE_M)
    assert est.observed and est.points_u > 200 and est.points_v > 200
    err = np.asarray(est.rotation_deg) - np.asarray(turn)
    assert np.all(np.abs(err[:2]) < 0.06), est.rotation_deg  # measured: 0.04 at most
    assert abs(err[2]) < 0.15, est.rotation_deg  # measured: 0.11 (about the optical axis edges move least)
    assert abs(est.shift_px) < 0.2  # measured: 0.1 (no fattening in a ray-cast depth image)
    assert est.score > est.score_unturned or not any(turn)


def test_bare_wall_not_observed():
    est = estimate_turn([_frame((0.5, -0.4, 0.0), boxes=[])], DEPTH, COLOUR, BASELINE_M)
    assert not est.observed
    assert est.rotation_deg == (0.0, 0.0, 0.0)
    assert est.points_u == est.points_v == 0


def test_applied_and_recorded():
    """The registration's step: the turn observed is applied to the estimated registration and recorded."""
    reg = DepthRegistration(1.114, BASELINE_M, "depth", ok=True)
    applied, est = edge_turn_correction([_frame((0.5, -0.4, -0.15))], reg, reg)
    assert np.allclose(applied.depth_rotation_deg, (0.5, -0.4, -0.15), atol=0.15)
    assert applied.baseline_m == BASELINE_M and applied.ratio == reg.ratio
    rec = registration_record(applied, est)
    assert rec["depth_rotation_observed"]
    assert rec["depth_rotation_deg_applied"] == list(applied.depth_rotation_deg)
    assert rec["depth_rotation_deg_estimated"] == list(applied.depth_rotation_deg)
    bare, est = edge_turn_correction([_frame((0.5, -0.4, 0.0), boxes=[])], reg, reg)
    assert bare == reg and not registration_record(bare, est)["depth_rotation_observed"]


def test_small_turn_recorded_not_applied():
    """A turn below ``min_deg`` about x and y (the estimate's spread on unturned rows) is recorded, not applied."""
    reg = DepthRegistration(1.114, BASELINE_M, "depth", ok=True)
    applied, est = edge_turn_correction([_frame((0.5, -0.4, -0.15))], reg, reg, min_deg=0.15)
    assert np.allclose(applied.depth_rotation_deg, (0.5, -0.4, -0.15), atol=0.15)  # large: applied
    kept, est = edge_turn_correction([_frame((0.0, 0.0, 0.0))], reg, reg, min_deg=0.15)
    assert est.edge_turn.observed and kept == reg  # ~0 read, not applied
    assert registration_record(kept, est)["depth_rotation_observed"]
