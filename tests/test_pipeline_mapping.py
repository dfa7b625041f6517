"""The Gaussian mapper inside the pipeline: a short mapped run on the bundled TUM frames."""

from __future__ import annotations

import json
import sys
import threading

import numpy as np
import pytest
import torch

from gsslam.config import load_config
from gsslam.datasets.base import open_dataset
from gsslam.io.ply import read_ply
from gsslam.io.trajectory import read_tum
from gsslam.mapping import rasterize_cpu
from gsslam.run.sequence import run_dataset

pytestmark = pytest.mark.slow  # end-to-end runs

# small map: 80x60, few steps (CI time); PSNR bounds below were measured at these settings
SMALL = [
    "loop.enabled=false",
    "mapper.max_side=80",
    "mapper.iterations=10",
    "mapper.pose_iterations=5",
    "mapper.final_iterations_per_keyframe=5",
    "mapper.device=cpu",
]
N_FRAMES = 36  # 8-10 keyframes: one full submap and a tail submap


@pytest.fixture(scope="module", autouse=True)
def one_torch_thread():
    # The CPU rasterizer's threads spin when the cores are shared with other jobs (15x slower measured).
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def _run(bundled_tum, out, extra=(), stages=None):
    ds = open_dataset("tum", bundled_tum)
    cfg = load_config(None, SMALL + list(extra), mode="rgbd")
    run_dataset(ds, cfg, out, max_frames=N_FRAMES, stages=stages)
    return json.loads((out / "metrics.json").read_text())


STAGES: list[tuple[str, int, int]] = []
IN_FINAL_PASS: set[tuple[tuple[str, ...], int, int]] = set()  # (Python threads, torch's, compositor's)


def _stage(*a) -> None:
    STAGES.append(a)
    if a[0] == "final pass":
        # the run's threads; tqdm's monitor is left by earlier tests of the same process (a progress bar)
        names = tuple(sorted(t.name for t in threading.enumerate() if t.name != "tqdm_monitor"))
        IN_FINAL_PASS.add((names, torch.get_num_threads(), rasterize_cpu.band_threads()))


@pytest.fixture(scope="module")
def mapped_run(bundled_tum, tmp_path_factory):
    out = tmp_path_factory.mktemp("mapped")
    return out, _run(bundled_tum, out, stages=_stage)


def test_stages_report_their_progress(mapped_run):
    out, m = mapped_run
    names = list(dict.fromkeys(s for s, _, _ in STAGES))
    assert names == ["batch refinement", "final pass", "outputs", "outputs: map metrics"]
    last = {s: (d, t) for s, d, t in STAGES}
    assert last["final pass"] == (m["mapper"]["final_iterations"],) * 2
    d, t = last["outputs: map metrics"]
    assert d == t == m["mapper"]["n_keyframes"] + m["mapper"]["n_other"]
    # the true peak: measured after the map's evaluation, never below the one before it
    assert m["peak_rss_mb"] >= m["peak_rss_mb_before_outputs"] > 100
    # the run's own peak (reset when it started; a batch runs many in one process), on Linux
    assert m["peak_rss_scope"] == ("run" if sys.platform.startswith("linux") else "process")


def test_final_pass_has_the_cores_to_itself(mapped_run):
    """Frame prefetching and the rest of the run are over: the pass's compositor takes every core."""
    from gsslam.mapping.keyframes import available_cores

    _, m = mapped_run
    assert IN_FINAL_PASS == {((threading.main_thread().name,), 1, available_cores())}
    assert m["mapper"]["final_threads"] == available_cores()


def test_mapped_run_writes_map_renders_and_metrics(mapped_run):
    out, m = mapped_run
    mp = m["mapper"]
    for key in (
        "num_gaussians",
        "size_mb",
        "psnr_keyframes",
        "ssim_keyframes",
        "psnr_other",
        "ssim_other",
        "n_keyframes",
        "n_other",
        "psnr_keyframes_native",
        "ssim_keyframes_native",
        "psnr_other_native",
        "ssim_other_native",
        "final_seconds",
        "window_seconds",
        "depth_prior_factors",
    ):
        assert key in mp, key
    assert m["submaps"] >= 2 and mp["keyframes"] == m["keyframes"]
    ply = read_ply(out / "map.ply")
    assert len(ply.means) == mp["num_gaussians"] > 500
    assert np.all(np.isfinite(ply.means))
    assert len(list((out / "renders").glob("keyframe_*.png"))) >= 2
    worst = sorted((out / "renders").glob("worst_*.png"))  # where the map is weak, at 640x480
    assert len(worst) == 2 == len(mp["worst_keyframes"])
    import cv2

    assert cv2.imread(str(worst[0])).shape == (480, 3 * 640, 3)
    assert (out / "intrinsics.yaml").is_file()
    # measured 25.2 dB keyframes / 24.8 dB held-out at 80x60 with the final pass (45 steps), 22.3 /
    # 22.0 dB without it (a blank render scores ~8 dB)
    assert mp["final_iterations"] == 5 * mp["keyframes"]  # final_iterations_per_keyframe x keyframes
    assert mp["psnr_keyframes"] > 23.5
    assert mp["psnr_other"] > 23.0 and mp["n_other"] >= 15
    assert (mp["native_width"], mp["native_height"]) == (640, 480)
    assert 15.0 < mp["psnr_keyframes_native"] < mp["psnr_keyframes"]  # 80 px map, 640 px images
    # the input-resolution scores are the means over the frames the metrics name (12 + 12 at most)
    named = mp["native_frames"]
    assert len(named["keyframes"]) == mp["n_keyframes_native"] == min(12, mp["n_keyframes"])
    assert len(named["held_out"]) == mp["n_other_native"] == min(12, mp["n_other"])
    per = mp["per_frame_psnr_native"]
    assert sorted(per) == sorted(str(i) for i in named["keyframes"] + named["held_out"])
    assert mp["psnr_keyframes_native"] == pytest.approx(np.mean([per[str(i)] for i in named["keyframes"]]))
    assert mp["psnr_other_native"] == pytest.approx(np.mean([per[str(i)] for i in named["held_out"]]))
    assert not mp["final_capped"] and mp["final_visits_min"] == mp["final_visits_max"] == 5
    assert mp["depth_prior_factors"] == 0  # depth_feedback is off by default
    assert mp["rasterizer_backend"] == ("c" if rasterize_cpu.available(torch.zeros(1)) else "torch")
    assert m["ate"]["rmse_m"] < 0.02


def test_render_command_reads_a_run(mapped_run, tmp_path):
    from gsslam.run.render import render_run

    out, m = mapped_run
    n = render_run(out, tmp_path / "r", every=10)
    assert n == len(range(0, m["frames_posed"], 10))
    assert len(list((tmp_path / "r").glob("render_*.png"))) == n


def test_depth_feedback_adds_priors_that_move_the_estimate(bundled_tum, mapped_run, tmp_path):
    out_off, _ = mapped_run
    # feedback_min_age=0: the whole map counts as converged (36 frames have no revisit; the default
    # waits for Gaussians 16 keyframes old, tests/mapping/test_registration.py)
    m = _run(bundled_tum, tmp_path, ["mapper.depth_feedback=true", "mapper.feedback_min_age=0"])
    assert m["mapper"]["depth_prior_factors"] >= 2
    off, on = read_tum(out_off / "keyframes.tum"), read_tum(tmp_path / "keyframes.tum")
    assert len(off) == len(on)
    moved = np.abs(off.positions - on.positions).max()
    assert moved > 1e-6  # the graph saw the priors
    assert m["ate"]["rmse_m"] < 0.02


def test_registration_feedback_adds_factors_that_move_the_estimate(bundled_tum, mapped_run, tmp_path):
    out_off, m_off = mapped_run
    # off by default for RGB-D (mapper.registration_feedback_rgbd); on, 36 frames give fewer than
    # feedback_min_age=16 keyframes: nothing converged, none sent
    assert m_off["mapper"]["registration_factors"] == 0
    extra = ["mapper.registration_feedback=true", "mapper.registration_feedback_rgbd=true", "mapper.feedback_min_age=0"]
    m = _run(bundled_tum, tmp_path, extra)
    mp = m["mapper"]
    assert mp["registration_factors"] >= 1  # measured 1 at 80x60 on 36 frames (most gated: coverage)
    assert mp["registration_factors"] + mp["registrations_gated"] + mp["registrations_withheld"] <= mp["keyframes"]
    off, on = read_tum(out_off / "keyframes.tum"), read_tum(tmp_path / "keyframes.tum")
    assert len(off) == len(on)
    moved = np.abs(off.positions - on.positions).max()
    # sent, but the RGB-D graph barely moves: measured 4e-8 m, the size of run-to-run noise (its flow
    # factors are far stronger than an honest map registration; docs/results.md, "Feedback, session 3")
    assert moved < 1e-3
    assert m["ate"]["rmse_m"] < 0.02


def test_mapper_disabled_leaves_no_map(bundled_tum, tmp_path):
    ds = open_dataset("tum", bundled_tum)
    cfg = load_config(None, ["mapper.enabled=false", "loop.enabled=false"], mode="rgbd")
    m = run_dataset(ds, cfg, tmp_path, max_frames=12).metrics
    assert m["mapper"] is None and not (tmp_path / "map.ply").exists()


def test_final_joint_refinement_reports_its_own_psnr_and_ate(bundled_tum, mapped_run, tmp_path):
    out_off, off = mapped_run
    m = _run(bundled_tum, tmp_path, ["mapper.final_pose_iterations=40"])
    mp = m["mapper"]
    assert mp["final_pose_iterations"] == 40
    assert 0.0 < mp["final_pose_moved_max"] < 0.02  # anchored: millimetres, not centimetres
    assert mp["psnr_keyframes_refined_poses"] > 23.5
    assert mp["ate_keyframes_refined_poses"]["rmse_m"] < 0.02
    # the output trajectory stays the graph's: the same as the run without the refinement
    on_kf, off_kf = read_tum(tmp_path / "keyframes.tum"), read_tum(out_off / "keyframes.tum")
    assert np.array_equal(on_kf.positions, off_kf.positions)
    assert "psnr_keyframes_refined_poses" not in off["mapper"]


def test_rgbd_trajectory_does_not_depend_on_the_map_at_the_defaults(bundled_tum, mapped_run, tmp_path):
    """At the RGB-D defaults nothing goes from the map to the graph (registration feedback is mono-only,
    depth feedback and the mapper's pose refinement are off, the map draws no random numbers the
    frontend uses), so the `tracking` suite's map-off numbers are the trajectory of a run with the map.
    Measured on the hidden room's proxy (teddy200_s2_blur_7scenes, 300 frames, loops on): trajectory.tum
    byte-identical with the map on and off (docs/results.md, "The map's effect on the trajectory,
    session 9")."""
    out_on, _ = mapped_run
    m = _run(bundled_tum, tmp_path, ["mapper.enabled=false"])
    assert m["mapper"] is None
    on, off = read_tum(out_on / "trajectory.tum"), read_tum(tmp_path / "trajectory.tum")
    assert len(on) == len(off) == N_FRAMES
    assert np.array_equal(on.poses, off.poses)
