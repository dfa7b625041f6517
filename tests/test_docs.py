"""Docs that must stay true to the code."""

import importlib.util
import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _load_doc_maker():
    spec = importlib.util.spec_from_file_location("make_config_doc", REPO / "docs" / "make_config_doc.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_config_doc_is_up_to_date():
    current = (REPO / "docs" / "config.md").read_text()
    assert current == _load_doc_maker().render(), (
        "docs/config.md is stale: run python docs/make_config_doc.py"
    )


def test_readme_test_command_is_what_ci_runs():
    readme = (REPO / "README.md").read_text()
    ci = (REPO / ".ci" / "run").read_text()
    block = readme.split("## Tests", 1)[1]
    command = re.search(r"```bash\n(.+?)\n```", block, re.S).group(1).strip()
    assert command in ci


def test_cli_help_lists_every_command():
    out = subprocess.run(
        [sys.executable, "-m", "gsslam", "--help"], capture_output=True, text=True, check=True
    )
    for cmd in ("run", "demo", "eval", "render", "bench", "batch", "export", "view"):
        assert cmd in out.stdout
