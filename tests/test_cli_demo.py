"""`gsslam demo`: the bundled RGB-D sequence, evaluated, with the outputs named (a short prefix here)."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from gsslam import cli
from gsslam.cli import app


def test_demo_runs_evaluates_and_names_its_outputs(tmp_path):
    out = tmp_path / "demo"
    args = ["demo", "--out", str(out), "--max-frames", "12", "--no-progress", "--set", "mapper.enabled=false"]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    assert f"outputs in {out}/" in res.output and "align=se3" in res.output
    for name in ("trajectory.tum", "metrics.json", "config.yaml", "ate.png"):
        assert (out / name).is_file(), name
    assert json.loads((out / "metrics.json").read_text())["ate"]["rmse_m"] < 0.05


def test_demo_outside_a_clone_says_what_to_do(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(cli, "DEMO_SEQUENCE", "data/not_bundled_here")
    res = CliRunner().invoke(app, ["demo", "--out", str(tmp_path / "demo")])
    text = " ".join(res.output.replace("│", " ").split())  # typer may draw a box around the message
    assert res.exit_code == 2 and "run from a clone of gsslam or pass --data" in text
