"""The baseline from the colour camera's motion (flow) against the depth camera's (ICP): hand-eye
(frontend/registration_handeye.py, session 15).

Ray-cast Kinect v1 views of the long synthetic room (depth noise, quantization, holes), the depth camera
25 mm beside colour at 1.114x its focal, the true flow; each pair's ICP motion slid 7 mm along the direction
its depth geometry observes least (what ICP does on the room's bare walls, docs/results.md, sessions 13-15).
Held fixed, the slid motions put the baseline centimetres off; the hand-eye fit re-solves the depth motion
with smoothed normals, weighs what the depth geometry leaves free by its covariance and finds the truth.
Colour motions that disagree with the depth motions beyond any baseline (what the TUM teddy playbacks show)
make the pairs inconsistent: not used."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from gsslam.datasets.synthetic import SyntheticDataset
from gsslam.frontend.depth_registration import DepthRegistration, pair_baselines
from gsslam.frontend.registration_handeye import MAX_MEDIAN_CHI2, handeye_baseline
from gsslam.frontend.registration_joint import depth_information
from helpers.registration_pair import true_pair

KINECT_RATIO = 1.114
BASELINE_M = 0.025
ROOM = dict(n_frames=1000, width=320, height=240, scene="furnished_room", trajectory="room_walk", seed=0)
RAYCAST = {"baseline_m": BASELINE_M, "focal_scale": KINECT_RATIO, "report": "depth", "raycast": True}
SLIDE_M = 0.007
PAIRS = ((30, 32), (34, 36), (100, 104), (200, 204))


def _pairs(colour_offset_m: float = 0.0):
    """True pairs with the ICP motion slid; ``colour_offset_m``: the colour camera's motion moved along its
    optical axis by that much, alternating in sign (a disagreement no baseline explains)."""
    misreg = SyntheticDataset(**ROOM, misregister=RAYCAST, sensor="kinect_v1")
    registered = SyntheticDataset(**ROOM)
    reg = DepthRegistration(KINECT_RATIO, 0.0, "depth")
    depth = reg.depth_intrinsics(misreg.intrinsics)
    c = registered.intrinsics
    out = []
    for j, (a, b) in enumerate(PAIRS):
        p = true_pair(misreg, registered, a, b, BASELINE_M)
        if colour_offset_m:
            T_cb_ca = np.linalg.inv(misreg[b].T_world_cam_gt) @ misreg[a].T_world_cam_gt
            T_cb_ca[2, 3] += colour_offset_m * (-1) ** j
            us, vs = p.uv_a[:, 0].astype(int), p.uv_a[:, 1].astype(int)
            z = registered[a].depth[vs, us].astype(np.float64)
            X = np.stack([(us - c.cx) / c.fx * z, (vs - c.cy) / c.fy * z, z], 1)
            X = X @ T_cb_ca[:3, :3].T + T_cb_ca[:3, 3]
            uv_b = np.stack([c.cx + c.fx * X[:, 0] / X[:, 2], c.cy + c.fy * X[:, 1] / X[:, 2]], 1)
            p = replace(p, uv_b=uv_b)
        H = depth_information(p.raw_a, p.raw_b, depth, p.T_b_a)
        _, V = np.linalg.eigh(H[:3, :3])  # translation: the least observed direction first
        T = p.T_b_a.copy()
        T[:3, 3] += SLIDE_M * V[:, 0]
        out.append(replace(p, T_b_a=T))
    return misreg.intrinsics, reg, out


def test_hand_eye_finds_the_baseline_that_slid_motions_miss():
    intr, reg, pairs = _pairs()
    fixed = np.array(pair_baselines(pairs, intr, reg))
    he = handeye_baseline(
        pairs, [p.T_b_a for p in pairs], reg.colour_intrinsics(intr), reg.depth_intrinsics(intr), 0.035
    )
    print("fixed", fixed, "hand-eye", he)
    assert np.max(np.abs(fixed - BASELINE_M)) > 0.01, fixed
    assert abs(he.baseline_m - BASELINE_M) < 0.002, he
    assert np.allclose(he.pair_baselines_m, BASELINE_M, atol=0.005), he
    assert he.consistent and he.median_chi2 < MAX_MEDIAN_CHI2 / 5, he


def test_colour_motions_that_no_baseline_explains_are_not_used():
    intr, reg, pairs = _pairs(colour_offset_m=0.002)
    he = handeye_baseline(
        pairs, [p.T_b_a for p in pairs], reg.colour_intrinsics(intr), reg.depth_intrinsics(intr), 0.035
    )
    print("hand-eye", he)
    assert not he.consistent and he.median_chi2 > 4 * MAX_MEDIAN_CHI2, he
