"""The input-resolution evaluation on a fixed sample of frames: the same numbers as the full one there."""

from __future__ import annotations

import numpy as np
import torch

from gsslam.config import MapperConfig
from gsslam.mapping.mapper import GaussianMapper
from gsslam.mapping.outputs import evenly_spaced

CFG = MapperConfig(max_side=80, iterations=20, window=4, device="cpu", pose_refinement=False)


def test_evenly_spaced_keeps_the_ends_and_never_repeats():
    items = list(range(100, 161))  # 61 keyframes, as on teddy 200
    pick = evenly_spaced(items, 12)
    assert len(pick) == 12 == len(set(pick))
    assert pick[0] == 100 and pick[-1] == 160 and pick == sorted(pick)
    gaps = np.diff(pick)
    assert gaps.min() >= 5 and gaps.max() <= 6  # 60 / 11 = 5.45 apart
    assert evenly_spaced(items[:7], 12) == items[:7]  # fewer than asked: all of them
    assert evenly_spaced(items, 0) == [] and evenly_spaced([], 5) == []
    assert evenly_spaced(items, 1) == [100]


def test_sampled_native_scores_are_the_full_scores_on_the_named_frames(teddy_sequence):
    torch.manual_seed(0)
    m = GaussianMapper(CFG, teddy_sequence[0].intrinsics)
    kf = teddy_sequence[::2]  # frames 5, 25, 45 mapped; 15, 35, 55 held out
    for f in kf:
        m.add_keyframe(f, f.T_world_cam_gt, submap_id=0)
        m.optimize(15)
    poses = {f.index: f.T_world_cam_gt for f in teddy_sequence}
    full = m.evaluate(iter(teddy_sequence), poses, native=True)
    kfs = [f.index for f in kf]
    held = [f.index for f in teddy_sequence[1::2]]
    s_kf, s_held = evenly_spaced(kfs, 2), evenly_spaced(held, 2)
    assert s_kf == [5, 45] and s_held == [15, 55]
    part = m.evaluate(iter(teddy_sequence), poses, native=True, native_only=set(s_kf) | set(s_held))
    assert set(part["per_frame_psnr_native"]) == set(s_kf) | set(s_held)
    assert (part["n_keyframes_native"], part["n_other_native"]) == (2, 2)
    for i in s_kf + s_held:  # renders are deterministic: each sampled frame scores as in the full pass
        assert part["per_frame_psnr_native"][i] == full["per_frame_psnr_native"][i]
    mean_kf = np.mean([full["per_frame_psnr_native"][i] for i in s_kf])
    mean_held = np.mean([full["per_frame_psnr_native"][i] for i in s_held])
    assert abs(part["psnr_keyframes_native"] - mean_kf) < 1e-9
    assert abs(part["psnr_other_native"] - mean_held) < 1e-9
    # the sample is a sample: the frame left out (25) scored differently, so the means differ
    assert part["psnr_keyframes_native"] != full["psnr_keyframes_native"]
    # the mapper-resolution scores do not depend on the sample
    assert part["psnr_keyframes"] == full["psnr_keyframes"] and part["n_other"] == full["n_other"] == 3
