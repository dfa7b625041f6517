"""Frames of the bundled TUM fr3/teddy sequence with ground-truth poses, read directly (no loader)."""

from __future__ import annotations

from pathlib import Path

import pytest

from gsslam.types import Frame
from helpers.tum import load_tum


def load_tum_frames(root: Path, indices: list[int]) -> list[Frame]:
    """Frames ``indices`` of a TUM folder (nearest depth and GT pose by timestamp)."""
    return load_tum(root, indices, gt_pose="nearest")


@pytest.fixture(scope="session")
def teddy_frames(bundled_tum) -> list[Frame]:
    """Frames 5, 10, 15, 20 (after the first GT pose), 640x480 with depth and GT pose."""
    return load_tum_frames(bundled_tum, [5, 10, 15, 20])


@pytest.fixture(scope="session")
def teddy_sequence(bundled_tum) -> list[Frame]:
    """Six frames 10 apart (5, 15, ..., 55: about 25 cm of camera motion) with depth and GT pose."""
    return load_tum_frames(bundled_tum, [5, 15, 25, 35, 45, 55])
