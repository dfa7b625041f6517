"""gsslam's ATE / RPE equal evo's APE / RPE on the real TUM teddy ground truth vs a perturbed copy.

evo is a dev-only dependency (GPL): it is imported here, never from gsslam/.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
from conftest import perturb

from gsslam.eval.report import evaluate
from gsslam.io.trajectory import read_tum, write_tum

evo_metrics = pytest.importorskip("evo.core.metrics")
evo_sync = pytest.importorskip("evo.core.sync")
evo_files = pytest.importorskip("evo.tools.file_interface")

STATS = ("rmse", "mean", "median", "std", "min", "max", "sse")


def _evo(gt_path, est_path, align: str, max_dt: float, delta: int) -> dict:
    ref = evo_files.read_tum_trajectory_file(str(gt_path))
    est = evo_files.read_tum_trajectory_file(str(est_path))
    ref, est = evo_sync.associate_trajectories(ref, est, max_diff=max_dt)
    est = copy.deepcopy(est)
    if align != "none":
        est.align(ref, correct_scale=(align == "sim3"))
    out = {"ref_stamps": ref.timestamps, "est_stamps": est.timestamps}
    ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    out["ape"] = ape.get_all_statistics()
    for name, rel in (
        ("rpe_t", evo_metrics.PoseRelation.translation_part),
        ("rpe_r", evo_metrics.PoseRelation.rotation_angle_deg),
    ):
        rpe = evo_metrics.RPE(rel, delta=delta, delta_unit=evo_metrics.Unit.frames)
        rpe.process_data((ref, est))
        out[name] = rpe.get_all_statistics()
    return out


def _check(gt_path, est_path, align: str, max_dt: float = 0.02, delta: int = 1, one_to_one=False) -> None:
    gt, est = read_tum(gt_path), read_tum(est_path)
    rep = evaluate(gt, est, align=align, max_dt=max_dt, rpe_delta=delta, one_to_one=one_to_one)
    ev = _evo(gt_path, est_path, align, max_dt, delta)
    np.testing.assert_array_equal(gt.timestamps[rep.association.gt_indices], ev["ref_stamps"])
    np.testing.assert_array_equal(est.timestamps[rep.association.est_indices], ev["est_stamps"])
    mine_all = {"ape": rep.ate.stats, "rpe_t": rep.rpe.translation, "rpe_r": rep.rpe.rotation_deg}
    for key, mine in mine_all.items():
        for s in STATS:
            assert getattr(mine, s) == pytest.approx(ev[key][s], abs=1e-6), (key, s)  # metres or degrees
    assert rep.ate.stats.rmse > 1e-3  # the comparison is not between two zeros


@pytest.mark.parametrize(
    "align, scale, every, delta",
    [("sim3", 0.4, 3, 1), ("sim3", 2.5, 1, 5), ("se3", 1.0, 2, 1), ("none", 1.0, 1, 2)],
)
def test_matches_evo_on_bundled_teddy(bundled_tum, tmp_path, align, scale, every, delta):
    gt_path = bundled_tum / "groundtruth.txt"
    rng = np.random.default_rng(7)
    est = perturb(read_tum(gt_path), rng, scale=scale, time_jitter=0.004, every=every)
    write_tum(est, tmp_path / "est.tum")
    _check(gt_path, tmp_path / "est.tum", align, delta=delta)


def test_matches_evo_when_estimate_is_longer(bundled_tum, tmp_path):
    # gt subsampled, estimate at full rate: association runs from the gt side.
    gt_full = read_tum(bundled_tum / "groundtruth.txt")
    rng = np.random.default_rng(8)
    est = perturb(gt_full, rng, scale=1.7, time_jitter=0.003)
    gt = type(gt_full)(gt_full.timestamps[::4], gt_full.poses[::4])
    write_tum(gt, tmp_path / "gt.tum")
    write_tum(est, tmp_path / "est.tum")
    _check(tmp_path / "gt.tum", tmp_path / "est.tum", "sim3")


def test_matches_evo_on_full_teddy(shared_data, tmp_path):
    gt_path = shared_data / "rgbd_dataset_freiburg3_teddy" / "groundtruth.txt"
    rng = np.random.default_rng(9)
    est = perturb(read_tum(gt_path), rng, scale=0.8, trans_noise=0.02, time_jitter=0.004, every=5)
    write_tum(est, tmp_path / "est.tum")
    _check(gt_path, tmp_path / "est.tum", "sim3", delta=10)


def test_one_to_one_default_differs_from_evo_only_by_repeated_partners(bundled_tum, tmp_path):
    # Jitter up to the whole 0.02 s window: some ground-truth poses are nearest to two estimate stamps.
    gt_path = bundled_tum / "groundtruth.txt"
    gt = read_tum(gt_path)
    est = perturb(gt, np.random.default_rng(10), scale=1.3, time_jitter=0.02)
    write_tum(est, tmp_path / "est.tum")
    _check(gt_path, tmp_path / "est.tum", "sim3", one_to_one=False)  # evo's pairs: same numbers
    ev = _evo(gt_path, tmp_path / "est.tum", "sim3", 0.02, 1)
    rep = evaluate(gt, read_tum(tmp_path / "est.tum"))  # default: one-to-one
    gt_stamps = gt.timestamps[rep.association.gt_indices]
    assert len(np.unique(gt_stamps)) == len(gt_stamps)
    assert len(np.unique(ev["ref_stamps"])) < len(ev["ref_stamps"])  # evo repeats some partners
    assert set(gt_stamps) == set(ev["ref_stamps"])  # ...and keeps every partner once


def test_one_to_one_default_equals_evo_when_pairs_are_unique(bundled_tum, tmp_path):
    # Estimate at a third of the rate with small jitter: no partner is wanted twice.
    gt_path = bundled_tum / "groundtruth.txt"
    est = perturb(read_tum(gt_path), np.random.default_rng(11), scale=0.6, time_jitter=0.002, every=3)
    write_tum(est, tmp_path / "est.tum")
    _check(gt_path, tmp_path / "est.tum", "sim3", one_to_one=True)
