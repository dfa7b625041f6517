"""Optional dependencies: without them the features fail with an error naming the extra to install."""

from __future__ import annotations

import sys

import pytest

from gsslam.errors import GsslamError
from helpers.run_folder import make_run


@pytest.mark.parametrize(
    "modules,extra",
    [(("rerun",), "gsslam[viz]"), (("rosbags", "rosbags.highlevel", "rosbags.typesys"), "gsslam[ros]")],
)
def test_missing_package_names_the_extra(monkeypatch, tmp_path, modules, extra):
    for module in modules:  # submodules too: an earlier import leaves them in sys.modules
        monkeypatch.setitem(sys.modules, module, None)  # makes `import module` raise ImportError
    with pytest.raises(GsslamError, match=extra.replace("[", r"\[").replace("]", r"\]")):
        if modules[0] == "rerun":
            from gsslam.viz.rerun_log import record_run

            record_run(make_run(tmp_path / "run", n_kf=2, n_points=5), tmp_path / "x.rrd")
        else:
            from gsslam.datasets.base import open_dataset

            (tmp_path / "a.bag").write_bytes(b"")
            open_dataset("rosbag", tmp_path / "a.bag")


def test_cli_rejects_unknown_viewer_and_bad_dataset_arg(tmp_path):
    from typer.testing import CliRunner

    from gsslam.cli import app

    res = CliRunner().invoke(app, ["run", str(tmp_path), "--viz", "open3d"])
    assert res.exit_code != 0 and "rerun" in res.output
    res = CliRunner().invoke(app, ["run", str(tmp_path), "--dataset-arg", "no_equals_sign"])
    assert res.exit_code != 0 and "KEY=VALUE" in res.output
