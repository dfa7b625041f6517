"""Bad options, config values and output paths: one ``error:`` line, exit status 2, nothing touched."""

from __future__ import annotations

import numpy as np
import pytest
from reliability_helpers import BUNDLED_TUM, EXIT_USAGE, assert_error, gsslam, snapshot, teddy_copy

from gsslam.io.trajectory import read_tum, write_tum
from gsslam.types import Trajectory

FAST = ("--max-frames", "10", "--set", "mapper.enabled=false", "--no-progress")


@pytest.mark.parametrize(
    "override, fragments",
    [
        ("encoder.submap_size=-3", ("encoder.submap_size=-3", "an integer >= 1")),
        ("graph.flow_sigma_px=nan", ("graph.flow_sigma_px=nan", "a finite number > 0")),
        ("pipeline.track_points=0", ("pipeline.track_points=0", ">= 8")),
        ("mapper.device=gpu", ("mapper.device='gpu'", "'auto', 'cpu', 'cuda'")),
        ("encoder.nope=1", ("unknown config key 'encoder.nope'",)),
        ("mapper.iterations=many", ("mapper.iterations: expected an integer",)),
    ],
)
def test_bad_config_values(tmp_path, override, fragments):
    r = gsslam("run", BUNDLED_TUM, "--out", tmp_path / "out", "--set", override, "--no-progress")
    assert_error(r, *fragments)
    assert not (tmp_path / "out").exists()


def test_bad_values_in_a_config_file(tmp_path):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("encoder:\n  submap_size: -3\n")
    r = gsslam("run", BUNDLED_TUM, "--out", tmp_path / "out", "--config", cfg, "--no-progress")
    assert_error(r, "encoder.submap_size=-3", f"in config file {cfg}")
    cfg.write_bytes(bytes(range(256)))
    assert_error(gsslam("run", BUNDLED_TUM, "--config", cfg, "--out", tmp_path / "o"), str(cfg), "not a text")


@pytest.mark.parametrize("n", ["0", "-5"])
def test_max_frames_must_be_positive(tmp_path, n):
    r = gsslam("run", BUNDLED_TUM, "--out", tmp_path / "out", "--max-frames", n)
    assert_error(r, "--max-frames", "greater than or equal to 1", "gsslam run --help")
    assert not (tmp_path / "out").exists()


def test_usage_errors(tmp_path):
    assert_error(gsslam("bench", "graph", "--sizes", "a,b"), "--sizes", "comma-separated integers")
    assert_error(gsslam("bench", "loop", "--sizes", "10,-1"), "--sizes", "positive")
    assert_error(gsslam("nosuch"), "No such command")
    assert_error(gsslam("run"), "Missing argument")
    assert_error(gsslam("run", BUNDLED_TUM, "--dataset", "nope", "--out", tmp_path / "o"), "unknown dataset")
    assert gsslam().returncode == EXIT_USAGE  # no arguments: the help, status 2 (as click)


def test_eval_refuses_unsorted_estimates(tmp_path):
    gt = read_tum(BUNDLED_TUM / "groundtruth.txt")
    idx = np.arange(0, len(gt), 3)
    idx[[5, 6]] = idx[[6, 5]]
    est = tmp_path / "est.tum"
    write_tum(Trajectory(gt.timestamps[idx], gt.poses[idx]), est)
    before = snapshot(tmp_path)
    r = gsslam("eval", BUNDLED_TUM / "groundtruth.txt", est)
    assert_error(r, str(est), "pose 7", "comes before", "sort the file by time")
    assert r.stdout == "" and snapshot(tmp_path) == before


def test_exit_codes_are_documented(repo_root):
    from gsslam import cli

    doc = (repo_root / "docs" / "run_folders.md").read_text()
    for code in (cli.EXIT_OK, cli.EXIT_FAILURE, cli.EXIT_USAGE, cli.EXIT_SIGINT, cli.EXIT_SIGTERM):
        assert f"| {code} " in doc, code


def test_tracebacks_become_one_line_runtime_failures(monkeypatch, capsys, tmp_path):
    """An unexpected exception (a bug) is one line with exit status 1, the traceback only with -v."""
    from gsslam import cli

    seq = teddy_copy(tmp_path, n=3)

    def boom(*args, **kwargs):
        raise ZeroDivisionError("boom")

    monkeypatch.setattr("gsslam.run.sequence.run_sequence", boom)
    code = cli.run_cli(["run", str(seq), "--out", str(tmp_path / "o"), "--no-progress"])
    err = capsys.readouterr().err
    assert code == cli.EXIT_FAILURE and "Traceback" not in err
    assert err.strip().splitlines()[-1].startswith("error: unexpected ZeroDivisionError: boom")
