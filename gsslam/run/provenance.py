"""Where a run's numbers come from: versions, commit, command line, dataset, config hash, rasterizer.

Recorded in ``metrics.json`` under ``"provenance"``, so two runs can be compared (or not) knowingly.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from importlib import metadata
from pathlib import Path

import gsslam
from gsslam.config import Config, config_to_dict


def config_hash(cfg: Config) -> str:
    """SHA-256 of the resolved config (canonical JSON, sorted keys)."""
    text = json.dumps(config_to_dict(cfg), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def git_commit() -> str | None:
    """The commit of the gsslam checkout (``+dirty`` with local changes), or None when not a git checkout."""
    root = Path(gsslam.__file__).resolve().parents[1]
    if not (root / ".git").exists():
        return None
    try:
        head = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5
        )
        if head.returncode != 0:
            return None
        dirty = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=5,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")


def _version(dist: str) -> str | None:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def _command(argv: list[str]) -> list[str]:
    """The command line; ``python -m gsslam`` is written as ``gsslam``."""
    argv = list(argv)
    if argv and Path(argv[0]).name == "__main__.py" and Path(argv[0]).parent.name == "gsslam":
        argv[0] = "gsslam"
    return argv


def provenance(cfg: Config, dataset_path: str | Path | None, argv: list[str] | None = None) -> dict:
    """The provenance record of a run (the rasterizer backends are added when the run ends)."""
    import cv2
    import numpy as np

    return {
        "gsslam_version": gsslam.__version__,
        "git_commit": git_commit(),
        "command": _command(sys.argv if argv is None else argv),
        "dataset_path": str(Path(dataset_path).resolve()) if dataset_path is not None else None,
        "config_sha256": config_hash(cfg),
        "python": sys.version.split()[0],
        "versions": {
            "torch": _version("torch"),
            "gtsam": _version("gtsam"),
            "opencv": cv2.__version__,
            "numpy": np.__version__,
        },
    }
