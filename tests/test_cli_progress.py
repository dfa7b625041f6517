"""The CLI's progress bar follows the run's stages, each with its own total."""

from __future__ import annotations

from gsslam.cli_progress import StageBar


def test_stage_bar_restarts_at_every_stage(capsys):
    bar = StageBar()
    bar.frames(10, 20, 5.0)
    assert (bar.bar.n, bar.bar.total) == (10, 20) and bar.bar.desc.startswith("tracking")
    bar.stage("final pass", 0, 2000)
    bar.stage("final pass", 500, 2000)
    assert (bar.bar.n, bar.bar.total) == (500, 2000) and bar.bar.desc.startswith("final pass")
    bar.stage("outputs: map metrics", 3, 80)
    assert (bar.bar.n, bar.bar.total) == (3, 80) and bar.bar.desc.startswith("outputs: map metrics")
    bar.close()
    assert "final pass" in capsys.readouterr().err
