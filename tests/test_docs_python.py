"""docs/python.md: its example runs as written (from a folder that has the bundled data)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.slow  # two short end-to-end runs


def test_python_page_example_runs(tmp_path, monkeypatch, capsys):
    text = (REPO / "docs" / "python.md").read_text()
    blocks = re.findall(r"```python\n(.+?)```", text, re.S)
    assert len(blocks) == 1
    (tmp_path / "data").symlink_to(REPO / "data")
    monkeypatch.chdir(tmp_path)
    exec(compile(blocks[0], "docs/python.md", "exec"), {"__name__": "docs_python"})
    out = capsys.readouterr().out
    assert (tmp_path / "python_out" / "trajectory.tum").is_file()
    assert (tmp_path / "python_run" / "metrics.json").is_file()
    final, online = map(float, re.search(r"ATE final ([\d.]+) mm, online ([\d.]+) mm", out).groups())
    assert final < 10 and online < 2 * final + 2  # measured: 4.3 mm / 6.3 mm (40 frames)


def test_import_gsslam_exposes_the_facade_cheaply():
    import subprocess
    import sys

    code = (
        "import sys, gsslam; assert callable(gsslam.run) and 'gtsam' not in sys.modules "
        "and 'torch' not in sys.modules; gsslam.Slam; gsslam.Plugin; print('ok')"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "ok"
