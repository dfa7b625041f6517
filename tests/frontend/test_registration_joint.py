"""The baseline from motions re-solved with the flow (frontend/registration_joint.py, session 14).

Ray-cast views of the long synthetic room, the depth camera 25 mm beside colour at 1.114x its focal, the
true flow; each pair's depth-camera motion slid 7 mm along the direction its depth geometry observes
least (what ICP does on the room's bare walls, docs/results.md, session 13). Held fixed, the slid motions
put the baseline centimetres off; re-solved with the flow (the ICP motion a prior), back at the truth."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gsslam.config import FlowConfig
from gsslam.datasets.synthetic import SyntheticDataset
from gsslam.frontend.colour_focal import flow_pairs, mean_cost
from gsslam.frontend.depth_registration import DepthRegistration, pair_baselines
from gsslam.frontend.flow import make_flow_estimator
from gsslam.frontend.registration_joint import depth_information, joint_baseline, profile_min
from helpers.registration_pair import true_pair

KINECT_RATIO = 1.114
BASELINE_M = 0.025
ROOM = dict(n_frames=1000, width=320, height=240, scene="furnished_room", trajectory="room_walk", seed=0)
RAYCAST = {"baseline_m": BASELINE_M, "focal_scale": KINECT_RATIO, "report": "depth", "raycast": True}
SLIDE_M = 0.007


def _slid_pairs():
    misreg = SyntheticDataset(**ROOM, misregister=RAYCAST)
    registered = SyntheticDataset(**ROOM)
    reg = DepthRegistration(KINECT_RATIO, 0.0, "depth")
    depth = reg.depth_intrinsics(misreg.intrinsics)
    out = []
    for a, b in ((30, 32), (100, 104), (200, 204)):
        p = true_pair(misreg, registered, a, b, BASELINE_M)
        H = depth_information(p.raw_a, p.raw_b, depth, p.T_b_a)
        _, V = np.linalg.eigh(H[:3, :3])  # translation: the least observed direction first
        T = p.T_b_a.copy()
        T[:3, 3] += SLIDE_M * V[:, 0]
        out.append(replace(p, T_b_a=T))
    return misreg.intrinsics, reg, out


def test_motions_re_solved_with_the_flow_find_the_baseline_that_slid_motions_miss():
    intr, reg, pairs = _slid_pairs()
    fixed = np.array(pair_baselines(pairs, intr, reg))
    b, alone = joint_baseline(
        pairs, [p.T_b_a for p in pairs], reg.colour_intrinsics(intr), reg.depth_intrinsics(intr), 0.1
    )
    print("fixed", fixed, "joint", b, alone)
    assert np.max(np.abs(fixed - BASELINE_M)) > 0.01, fixed
    assert abs(b - BASELINE_M) < 0.002 and np.allclose(alone, BASELINE_M, atol=0.004), (b, alone)


def test_profile_min_fits_a_parabola_over_a_bumpy_profile():
    xs = np.arange(-0.03, 0.1001, 0.0025)
    bumps = np.where(np.arange(len(xs)) % 2 == 0, 0.0, 3e-6)  # the grid-scale bumps of nearest-pixel reads
    cs = (xs - 0.0263) ** 2 + bumps
    assert abs(profile_min(xs, cs) - 0.0263) < 3e-4


@pytest.mark.slow  # ~1 min CPU: 12 ray-cast Kinect frames, flow + ICP pairs with two DIS presets
def test_the_medium_flow_observes_the_baseline_that_the_ultrafast_flow_biases():
    """The room's first pairs (frames 30-39) with the true depth-camera motion: the flow alone sets the
    baseline. DIS ultrafast puts it ~9 mm long (its flow is biased by ~0.01 px, the size of the baseline's
    effect); DIS medium (``encoder.colour_registration_flow_preset``) near the truth (session 14)."""
    ds = SyntheticDataset(**ROOM, misregister=RAYCAST, sensor="kinect_v1")
    reg = DepthRegistration(KINECT_RATIO, 0.0, "depth")
    colour, depth = reg.colour_intrinsics(ds.intrinsics), reg.depth_intrinsics(ds.intrinsics)
    T_cd = np.eye(4)
    T_cd[0, 3] = BASELINE_M  # the depth camera's centre in the colour frame
    ab = [(a, a + 2) for a in range(30, 38)]
    bs = np.arange(0.0, 0.0601, 0.001)
    found = {}
    for preset in ("ultrafast", "medium"):
        flow = make_flow_estimator(FlowConfig(dis_preset=preset))
        pairs, Ts = [], []
        for a, b in ab:
            fa, fb = ds[a], ds[b]
            got = flow_pairs([fa, fb], flow, gap=1, max_pairs=1)
            if got:
                pairs.append(got[0])
                T_cb_ca = np.linalg.inv(fb.T_world_cam_gt) @ fa.T_world_cam_gt
                Ts.append(np.linalg.inv(T_cd) @ T_cb_ca @ T_cd)  # the true depth-camera motion
        assert len(pairs) >= 4
        cost = [mean_cost(pairs, Ts, colour, (depth.fx, depth.fy), float(b))[0] for b in bs]
        found[preset] = profile_min(bs, np.array(cost))
    print(found)
    assert abs(found["medium"] - BASELINE_M) < 0.003, found
    assert abs(found["ultrafast"] - BASELINE_M) > abs(found["medium"] - BASELINE_M) + 0.004, found
