"""A 1 s gap in the input (30 frames of teddy dropped): detected, never a silently mixed ATE, and
RGB-D chains re-joined into one world frame (docs/run_folders.md)."""

from __future__ import annotations

import json

import pytest
from reliability_helpers import BUNDLED_TUM, _rows, gsslam, teddy_copy

from gsslam.eval.report import evaluate
from gsslam.io.trajectory import read_tum

FAST = ("--set", "mapper.enabled=false", "--no-progress")  # loop closure on: it re-localizes chains


@pytest.fixture(scope="module")
def gap_copy(tmp_path_factory):
    """Teddy frames 0-19 then 50-59: 1.04 s without frames between frame 19 and frame 20."""
    seq = teddy_copy(tmp_path_factory.mktemp("gap"), n=60)
    for lst in ("rgb.txt", "depth.txt"):
        head, rows = _rows(seq / lst)
        (seq / lst).write_text("\n".join(head + rows[:20] + rows[50:]) + "\n")
    return seq


def _run(seq, out, mode) -> dict:
    r = gsslam("run", seq, "--mode", mode, "--out", out, *FAST)
    assert r.returncode == 0, r.stderr
    m = json.loads((out / "metrics.json").read_text())
    m["stdout"] = r.stdout
    return m


def test_mono_detects_the_gap_and_reports_ate_per_chain(gap_copy, tmp_path):
    m = _run(gap_copy, tmp_path, "mono")
    kinds = [(e["frame"], e["kind"]) for e in m["events"]]
    assert (20, "gap") in kinds and (20, "new_chain") in kinds  # mono does not cross the gap
    assert m["chains"] == 2 and m["chains_in_world"] == 1  # a mono chain has its own scale: not joined
    assert m["ate"] is None and m["ate_keyframes"] is None  # no number mixing two unjoined chains
    per = m["ate_per_chain"]
    assert [c["chain"] for c in per] == [0, 1]
    assert sum(c["frames_posed"] for c in per) == m["frames_posed"]
    for c in per:  # each chain on its own is as good as the gap-free run (~0.3 cm on these frames)
        assert c["ate"]["pairs"] >= 8 and c["ate"]["rmse_m"] < 0.01, c
    assert "ATE RMSE chain 1" in m["stdout"] and "not joined" in m["stdout"]


def test_rgbd_chains_are_rejoined_within_1_5x_of_the_gap_free_run(gap_copy, tmp_path):
    m = _run(gap_copy, tmp_path / "gap", "rgbd")
    kinds = [e["kind"] for e in m["events"]]
    assert "gap" in kinds and "new_chain" in kinds and "rejoined" in kinds
    assert m["chains"] == 2 and m["chains_in_world"] == 2 and m["ate_per_chain"] is None
    reloc = m["loop_closure"]["relocalized"]
    assert [(r["chain"], r["to_chain"]) for r in reloc] == [(1, 0)]
    # the gap-free run, evaluated on the same frames
    full = _run(BUNDLED_TUM, tmp_path / "full", "rgbd")
    assert full["chains"] == 1
    gap_traj = read_tum(tmp_path / "gap" / "trajectory.tum")
    full_traj = read_tum(tmp_path / "full" / "trajectory.tum")
    keep = [i for i, t in enumerate(full_traj.timestamps) if abs(gap_traj.timestamps - t).min() < 1e-6]
    same = type(full_traj)(full_traj.timestamps[keep], full_traj.poses[keep])
    gt = read_tum(BUNDLED_TUM / "groundtruth.txt")
    base = evaluate(gt, same, align="se3").ate.stats.rmse
    rejoined = evaluate(gt, gap_traj, align="se3").ate.stats.rmse
    assert rejoined == pytest.approx(m["ate"]["rmse_m"], rel=1e-6)
    assert rejoined <= 1.5 * base, (rejoined, base)  # measured 0.57 cm vs 0.51 cm
