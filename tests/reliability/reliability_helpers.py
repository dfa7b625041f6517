"""Helpers for the reliability cases: run ``python -m gsslam`` as a user would, on copies of the
bundled data, and check that an error is one line, names what to fix and exits with the documented
status (docs/run_folders.md)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

from helpers.tum import copy_tum_prefix, list_entries

REPO = Path(__file__).resolve().parents[2]
BUNDLED_TUM = REPO / "data" / "rgbd_dataset_freiburg3_teddy_60"
EXIT_FAILURE, EXIT_USAGE, EXIT_SIGINT, EXIT_SIGTERM = 1, 2, 130, 143


def gsslam(*args: str | Path, cwd: Path | None = None, timeout: float = 300) -> subprocess.CompletedProcess:
    """``python -m gsslam ARGS`` with this checkout first on the path."""
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.run(
        [sys.executable, "-m", "gsslam", *map(str, args)],
        capture_output=True,
        text=True,
        env=env,
        cwd=cwd,
        timeout=timeout,
    )


def assert_error(r: subprocess.CompletedProcess, *fragments: str, code: int = EXIT_USAGE) -> str:
    """One ``error:`` line, last on stderr, holding every fragment; no traceback; the exit status."""
    assert "Traceback" not in r.stderr, r.stderr
    errors = [line for line in r.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, r.stderr
    assert r.stderr.strip().splitlines()[-1] == errors[0], r.stderr
    for f in fragments:
        assert f in errors[0], (f, errors[0])
    assert r.returncode == code, (r.returncode, r.stderr)
    return errors[0]




def teddy_copy(dst: Path, n: int = 12) -> Path:
    """The first ``n`` rgb/depth frames of the bundled TUM teddy (files and lists) and its ground truth.

    The folder name keeps ``freiburg3`` so the loader knows the camera."""
    return copy_tum_prefix(BUNDLED_TUM, dst / "rgbd_dataset_freiburg3_copy", n)


def list_files(root: Path, lst: str) -> list[Path]:
    return [root / row.split()[1] for row in list_entries(root / lst)[1]]


def edit_row(path: Path, k: int, fn) -> str:
    """Replace the ``k``-th data row of a text list by ``fn(fields)``; returns the new row."""
    head, rows = list_entries(path)
    rows[k] = " ".join(fn(rows[k].split()))
    path.write_text("\n".join(head + rows) + "\n")
    return rows[k]


def sevenscenes_from_teddy(dst: Path, n: int = 6) -> Path:
    """A 7-Scenes ``seq-01`` folder built from teddy frames: colour PNG, depth in millimetres, pose.txt."""
    teddy = teddy_copy(dst / "src", n)
    seq = dst / "scene" / "seq-01"
    seq.mkdir(parents=True)
    for i, (rgb, depth) in enumerate(zip(list_files(teddy, "rgb.txt"), list_files(teddy, "depth.txt"))):
        shutil.copy(rgb, seq / f"frame-{i:06d}.color.png")
        raw = cv2.imread(str(depth), cv2.IMREAD_UNCHANGED)  # TUM: 5000 per metre -> millimetres
        cv2.imwrite(str(seq / f"frame-{i:06d}.depth.png"), (raw // 5).astype(np.uint16))
        np.savetxt(seq / f"frame-{i:06d}.pose.txt", np.eye(4))
    return seq


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` with its bytes: to show that nothing of the user's changed."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}
