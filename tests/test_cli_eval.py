"""`gsslam eval`: table, JSON and PNG output; one-line errors with a non-zero exit status."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

from gsslam.cli import app
from gsslam.errors import GsslamError
from gsslam.geometry import make_T, so3_exp
from gsslam.io.trajectory import read_tum, write_kitti, write_tum
from gsslam.types import Trajectory


@pytest.fixture(scope="module")
def files(bundled_tum, tmp_path_factory):
    """The real teddy ground truth and a scaled, moved, noisy estimate of it (every 2nd pose)."""
    gt_path = bundled_tum / "groundtruth.txt"
    gt = read_tum(gt_path)
    rng = np.random.default_rng(5)
    R, s = so3_exp(np.array([0.3, -0.2, 1.0])), 0.5
    poses = gt.poses.copy()
    poses[:, :3, :3] = R @ poses[:, :3, :3]
    poses[:, :3, 3] = s * gt.positions @ R.T + [1.0, 2.0, 3.0] + rng.normal(scale=0.005, size=(len(gt), 3))
    d = tmp_path_factory.mktemp("cli_eval")
    write_tum(Trajectory(gt.timestamps[::2] + 0.003, poses[::2]), d / "est.tum")
    return gt_path, d / "est.tum", d


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "gsslam", "eval", *args], capture_output=True, text=True)


def test_table_json_and_plot(files):
    gt, est, d = files
    runner = CliRunner()
    res = runner.invoke(app, ["eval", str(gt), str(est)])
    assert res.exit_code == 0, res.output
    assert "ATE rmse" in res.output and "RPE rot rmse (d=1)" in res.output and "sim3" in res.output
    args = ["eval", str(gt), str(est), "--json", "--rpe-delta", "3", "--plot", str(d / "p.png")]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["association"]["pairs"] == 117
    assert out["ate"]["alignment"]["scale"] == pytest.approx(2.0, rel=0.01)
    # sqrt(3) * 0.005 m of noise, seen at 2x scale after alignment: ~1.7 cm
    assert out["ate"]["translation_m"]["rmse"] == pytest.approx(np.sqrt(3) * 0.01, rel=0.2)
    assert out["rpe"]["delta_frames"] == 3
    png = (d / "p.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    # SE(3) alignment cannot absorb the factor 2 in scale.
    res = runner.invoke(app, ["eval", str(gt), str(est), "--align", "se3", "--json"])
    assert json.loads(res.stdout)["ate"]["translation_m"]["rmse"] > 0.05


def test_kitti_format(files):
    gt_path, _, d = files
    gt = read_tum(gt_path)
    write_kitti(gt, d / "gt.txt")
    moved = gt.poses.copy()
    moved[:, :3, 3] += 0.1
    write_kitti(Trajectory(gt.timestamps, moved), d / "est.txt")
    res = CliRunner().invoke(
        app, ["eval", str(d / "gt.txt"), str(d / "est.txt"), "--format", "kitti", "--align", "none", "--json"]
    )
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["association"]["pairs"] == len(gt)
    assert out["ate"]["translation_m"]["mean"] == pytest.approx(0.1 * np.sqrt(3), abs=1e-9)


def test_errors_are_one_line_with_nonzero_exit(files, tmp_path):
    gt, est, _ = files
    bad = tmp_path / "bad.tum"
    bad.write_text("# ok\n1.0 0 0 0 0 0 0 1\n1.5 0 0 0 oops 0 0 1\n")
    two = tmp_path / "two.tum"
    write_tum(Trajectory([0.0, 1.0], np.stack([make_T(np.eye(3), [i, 0, 0]) for i in range(2)])), two)
    far = tmp_path / "far.tum"
    write_tum(Trajectory(read_tum(est).timestamps + 100.0, read_tum(est).poses), far)
    cases = [
        ((str(gt), str(tmp_path / "missing.tum")), "not found"),
        ((str(gt), str(bad)), f"{bad}:3: not a number"),
        ((str(gt), str(far)), "no timestamps of the estimate"),
        ((str(two), str(two)), "at least 3 associated poses"),
        ((str(gt), str(est), "--align", "affine"), "unknown alignment"),
        ((str(gt), str(est), "--format", "csv"), "unknown trajectory format"),
        ((str(gt), str(est), "--rpe-delta", "500"), "smaller --rpe-delta"),
    ]
    for args, msg in cases:
        r = _run(*args)
        assert r.returncode == 2, (args, r.stderr)
        assert r.stdout == ""
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("error: ") and msg in lines[0], r.stderr
        assert "Traceback" not in r.stderr


def test_cli_runner_surfaces_typed_error(files, tmp_path):
    gt, _, _ = files
    res = CliRunner().invoke(app, ["eval", str(gt), str(tmp_path / "missing.tum")])
    assert res.exit_code != 0
    assert isinstance(res.exception, GsslamError)


def test_help_texts():
    r = subprocess.run([sys.executable, "-m", "gsslam", "--help"], capture_output=True, text=True)
    assert r.returncode == 0 and "eval" in r.stdout
    r = CliRunner().invoke(app, ["eval", "--help"])
    assert r.exit_code == 0
    for word in ("--align", "--format", "--max-dt", "--rpe-delta", "--json", "--plot", "sim3", "kitti"):
        assert word in r.output
