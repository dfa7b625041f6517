"""End-to-end monocular runs on real data: every tracked frame gets a pose, Sim(3) ATE within the
bounds measured (with margin) on bundled TUM teddy and on EuRoC V1_01 (../shared), whose first 95
frames are a camera standing still (no parallax: the chain lives on placeholder depth)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gsslam.config import load_config
from gsslam.frontend.tracking import interpolate_poses

FAST = ["mapper.enabled=false", "loop.enabled=false"]
KITTI_BOUND = 0.003  # of the path length


def _run(path, name, tmp_path, max_frames=None, **kw) -> dict:
    from gsslam.run.sequence import run_sequence

    cfg = load_config(None, FAST, mode="mono")
    run_sequence(path, name, cfg, tmp_path, max_frames=max_frames, progress=False, **kw)
    return json.loads((tmp_path / "metrics.json").read_text())


@pytest.mark.slow
def test_mono_bundled_tum(bundled_tum, tmp_path):
    m = _run(bundled_tum, "tum", tmp_path)
    assert m["frames_posed"] == m["frames"] == 60
    assert m["chains"] == 1 and not [e for e in m["events"] if e["kind"] in ("graph", "encoder")]
    assert m["ate"]["align"] == "sim3"
    assert m["ate"]["rmse_m"] < 0.015, m["ate"]  # measured 0.59 cm (56 poses)


@pytest.mark.slow
def test_mono_euroc_static_start(shared_data, tmp_path):
    d = shared_data
    m = _run(
        d / "euroc_V1_01_easy",
        "euroc",
        tmp_path,
        gt_path=d / "euroc_V1_01_easy_groundtruth" / "V1_01_easy.csv",
    )
    assert m["frames_posed"] == m["frames"] == 95  # was 7 of 95: the shared frame had no depth
    assert m["chains"] == 1 and not [e for e in m["events"] if e["kind"] in ("graph", "new_chain")]
    assert m["ate"]["rmse_m"] < 0.0015, m["ate"]  # the drone stands still: measured 0.58 mm


@pytest.mark.slow
def test_mono_bundled_euroc_without_ground_truth(repo_root, tmp_path):
    """Bundled EuRoC prefix (20 frames, camera at rest, no GT): one chain, every frame posed, ~no motion."""
    from gsslam.io.trajectory import read_tum

    m = _run(repo_root / "data" / "euroc_V1_01_easy_20", "euroc", tmp_path)
    assert m["frames_posed"] == m["frames"] == 20 and m["chains"] == 1 and m["ate"] is None
    traj = read_tum(tmp_path / "trajectory.tum")
    assert len(traj) == 20 and np.abs(traj.poses[:, :3, 3]).max() < 0.05  # unit = scene depth


@pytest.mark.slow
def test_static_camera_gives_an_empty_map_that_is_reported_as_such(repo_root, tmp_path):
    """A camera at rest observes no depth: the mapper seeds nothing, and the run says so plainly."""
    from gsslam.run.sequence import run_sequence

    cfg = load_config(None, ["loop.enabled=false"], mode="mono")
    res = run_sequence(repo_root / "data" / "euroc_V1_01_easy_20", "euroc", cfg, tmp_path, progress=False)
    mp = json.loads((tmp_path / "metrics.json").read_text())["mapper"]
    assert mp["num_gaussians"] == 0 and mp["empty"] is True
    assert dict(res.summary_rows())["map"].startswith("empty: 0 Gaussians")
    assert (tmp_path / "map.ply").is_file()  # still written, with no vertices


@pytest.mark.slow
def test_mapped_mono_run_reports_a_non_empty_map(bundled_tum, tmp_path):
    from gsslam.run.sequence import run_sequence

    over = [
        "loop.enabled=false",
        "mapper.max_side=80",
        "mapper.iterations=5",
        "mapper.final_iterations_per_keyframe=2",
    ]
    res = run_sequence(bundled_tum, "tum", load_config(None, over, mode="mono"), tmp_path, max_frames=20,
                       progress=False)  # fmt: skip
    mp = json.loads((tmp_path / "metrics.json").read_text())["mapper"]
    assert mp["num_gaussians"] > 500 and mp["empty"] is False
    assert "Gaussians" in dict(res.summary_rows())["map"] and "PSNR" in dict(res.summary_rows())["map"]


def test_interpolate_poses_between_neighbours():
    from gsslam.geometry import make_T, so3_exp

    Ta = make_T(np.eye(3), np.array([0.0, 0.0, 0.0]))
    Tb = make_T(so3_exp(np.array([0.0, 0.0, 0.4])), np.array([1.0, 2.0, 0.0]))
    ts = {0: 0.0, 1: 0.25, 2: 1.0, 3: 2.0}
    out = interpolate_poses({0: Ta, 2: Tb}, [0, 1, 3], ts)
    assert set(out) == {1}  # known poses are kept, nothing is extrapolated past the last one
    assert np.allclose(out[1][:3, 3], [0.25, 0.5, 0.0])
    assert np.allclose(out[1][:3, :3], so3_exp(np.array([0.0, 0.0, 0.1])))


@pytest.mark.slow
def test_mono_kitti_forward_motion(shared_data, tmp_path):
    """KITTI 06, first 21 frames (~24 m of forward driving at ~10 Hz, every frame a keyframe)."""
    from gsslam.datasets.base import open_dataset

    m = _run(shared_data / "kitti_odometry", "kitti", tmp_path, max_frames=21, sequence="06")
    assert m["frames_posed"] == m["frames"] == 21 and m["chains"] == 1
    gt = open_dataset("kitti", shared_data / "kitti_odometry", sequence="06").ground_truth()
    path = float(np.sum(np.linalg.norm(np.diff(gt.poses[:21, :3, 3], axis=0), axis=1)))
    assert m["ate"]["rmse_m"] < KITTI_BOUND * path, (m["ate"], path)  # measured 0.11 % of 23.9 m
