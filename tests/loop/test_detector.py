"""Detection + verification on synthetic revisit / no-revisit scenes, and the ATE after closing."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gsslam.config import LoopConfig
from gsslam.geometry import sim3_scale, so3_log, split_sim3
from gsslam.loop import LoopDetector, LoopError
from helpers.loop_graph import ate, keyframe_positions, optimise
from helpers.loop_scenes import gt_relative, run_detector


def _check_loops_match_truth(sm, loops, trans_tol):
    assert loops, "no loop survived verification"
    for loop in loops.values():
        T_gt = gt_relative(sm, loop.i, loop.m)
        R, t, s = split_sim3(np.linalg.inv(T_gt) @ loop.T_i_m)
        assert np.degrees(np.linalg.norm(so3_log(R))) < 1.0, (loop.i, loop.m)
        assert np.linalg.norm(t) < trans_tol, (loop.i, loop.m)
        assert abs(s - 1.0) < 0.02
        assert len(loop) >= 30 and loop.inlier_ratio >= 0.25


@pytest.mark.parametrize("name", ["revisit_rgbd", "revisit_mono"])
def test_revisit_finds_correct_loops_and_closing_them_cuts_ate(name, request):
    sm, det, est, loops = request.getfixturevalue(name)
    mono = name.endswith("mono")
    # the revisit is found: the last submaps close onto the first ones, and only there
    assert any(lp.i >= 8 and lp.m <= 1 for lp in loops.values())
    assert all(lp.i >= 8 and lp.m <= 2 for lp in loops.values())
    # loop transforms match ground truth (local units of submap i)
    _check_loops_match_truth(sm, loops, trans_tol=0.03 * det.record(8).median_depth)
    # closing the loops in a graph over the submap transforms: ATE drops at least 3x
    gt = keyframe_positions(dict(enumerate(sm.T_world_local_gt)), sm.encodings)
    before = ate(keyframe_positions(est, sm.encodings), gt, with_scale=mono)
    after = ate(keyframe_positions(optimise(est, loops, mono), sm.encodings), gt, with_scale=mono)
    assert before > 0.05  # the injected drift is real
    assert after <= before / 3.0
    stats = det.stats.to_dict()
    assert stats["accepted"] == len(loops) and stats["detected"] >= stats["accepted"]
    assert stats["candidates"] >= stats["detected"]


def test_mono_loop_recovers_relative_scale(revisit_mono):
    sm, _, _, loops = revisit_mono
    for loop in loops.values():
        s_gt = sim3_scale(gt_relative(sm, loop.i, loop.m))
        assert abs(sim3_scale(loop.T_i_m) / s_gt - 1.0) < 0.02


def test_no_revisit_no_loop(corridor):
    det, _, loops = run_detector(corridor, "rgbd")
    assert loops == {}
    assert det.stats.accepted == 0


def test_permissive_candidates_still_verified_by_geometry(corridor):
    """With the overlap/score tests switched off every nearby submap reaches RANSAC; any loop
    that survives must be geometrically right (true overlap), never an appearance look-alike."""
    cfg = LoopConfig(min_overlap=-1.0, min_score=-1.0, max_candidates=10, skip_recent=1)
    det, _, loops = run_detector(corridor, "rgbd", cfg)
    assert det.stats.candidates > 0
    _check_loops_match_truth(corridor, loops, trans_tol=0.05)


def test_disabled_detector_does_nothing(revisit_rgbd):
    sm = revisit_rgbd[0]
    cfg = LoopConfig(enabled=False)
    det, _, loops = run_detector(sm, "rgbd", cfg)
    assert loops == {} and len(det) == 0 and det.stats.candidates == 0
    assert det.check_loops({}, {}) == []


def test_bad_input_raises(revisit_rgbd):
    sm = revisit_rgbd[0]
    det = LoopDetector(LoopConfig(), mode="rgbd")
    with pytest.raises(LoopError, match="keyframe images"):
        det.add_submap(0, sm.encodings[0], sm.images[0][:3])
    with pytest.raises(LoopError, match="add_submap"):
        det.detect(5, {})
    det.add_submap(3, sm.encodings[0], sm.images[0])
    with pytest.raises(LoopError, match="increase"):
        det.add_submap(2, sm.encodings[1], sm.images[1])
    with pytest.raises(LoopError, match="mode"):
        LoopDetector(dataclasses.replace(LoopConfig()), mode="stereo")
