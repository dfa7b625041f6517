"""The end-of-run pass: bounded steps, spent on the keyframes whose renders err most; native metrics."""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from gsslam.config import MapperConfig
from gsslam.mapping.final_pass import final_iterations
from gsslam.mapping.mapper import GaussianMapper

CFG = MapperConfig(max_side=80, iterations=20, window=4, device="cpu", pose_refinement=False)


def test_final_iterations_are_capped_by_steps_and_by_share_of_the_run():
    cfg = dataclasses.replace(CFG, final_iterations_per_keyframe=32, final_max_iterations=2000)
    assert final_iterations(cfg, 10) == 320  # short run: every keyframe its 32 steps
    assert final_iterations(cfg, 270) == 2000  # long run: the cap, not 8640
    assert final_iterations(dataclasses.replace(cfg, final_max_iterations=0), 270) == 8640
    share = dataclasses.replace(cfg, final_max_share=0.2)
    # 100 s run so far, 0.1 s per step: 20 % of the whole run is 25 s = 250 steps
    assert final_iterations(share, 270, step_seconds=0.1, run_seconds=100.0) == 270  # >= one epoch
    assert final_iterations(share, 100, step_seconds=0.1, run_seconds=100.0) == 250
    assert final_iterations(share, 100) == 2000  # no timings known: only the step cap


def test_capped_pass_spends_its_steps_on_the_worst_keyframe(teddy_frames):
    torch.manual_seed(0)
    cfg = dataclasses.replace(CFG, final_iterations_per_keyframe=40, final_max_iterations=60)
    m = GaussianMapper(cfg, teddy_frames[0].intrinsics)
    for f in teddy_frames[:3]:
        m.add_keyframe(f, f.T_world_cam_gt, submap_id=0)
        m.optimize(40)
    worst = teddy_frames[3]
    m.add_keyframe(worst, worst.T_world_cam_gt, submap_id=0)  # seeded, never optimised
    seen = []
    st = m.finalize(progress=lambda done, total: seen.append((done, total)))
    assert st["iterations"] == 60 and st["capped"] and st["uncapped_iterations"] == 160
    assert seen[-1] == (60, 60) and len(seen) == 60
    assert st["visits_min"] >= 1  # the first epoch visits every keyframe
    assert st["visits_max"] > 60 / 4  # and then not uniformly


def test_uncapped_pass_visits_every_keyframe_equally(teddy_frames):
    torch.manual_seed(0)
    cfg = dataclasses.replace(CFG, final_iterations_per_keyframe=5)
    m = GaussianMapper(cfg, teddy_frames[0].intrinsics)
    for f in teddy_frames[:3]:
        m.add_keyframe(f, f.T_world_cam_gt, submap_id=0)
        m.optimize(10)
    st = m.finalize()
    assert st["iterations"] == 15 and not st["capped"]
    assert st["visits_min"] == st["visits_max"] == 5


def test_native_metrics_render_at_the_input_resolution(teddy_frames):
    torch.manual_seed(0)
    m = GaussianMapper(CFG, teddy_frames[0].intrinsics)
    for f in teddy_frames[:2]:
        m.add_keyframe(f, f.T_world_cam_gt, submap_id=0)
        m.optimize(30)
    frames = teddy_frames[:3]
    ev = m.evaluate(iter(frames), {f.index: f.T_world_cam_gt for f in frames}, native=True)
    assert (ev["width"], ev["height"]) == (80, 60)
    assert (ev["native_width"], ev["native_height"]) == (640, 480)
    assert ev["n_keyframes_native"] == 2 and ev["n_other_native"] == 1
    # the 80 px map cannot hold the detail of 640 px images: native scores lower, but renders the scene
    assert 12.0 < ev["psnr_keyframes_native"] < ev["psnr_keyframes"]
    assert np.isfinite(ev["ssim_other_native"])
    only = m.evaluate(iter(frames), {f.index: f.T_world_cam_gt for f in frames}, native=True, native_only={5})
    assert only["n_keyframes_native"] == 1 and only["n_other_native"] == 0 and only["n_keyframes"] == 2
