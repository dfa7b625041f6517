"""nerfstudio transforms.json: OpenGL axes on disk, our poses back through our reader."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gsslam.geometry import make_T, so3_exp
from gsslam.io.nerfstudio import (
    NerfstudioError,
    NerfstudioFrame,
    parse_transforms,
    read_transforms,
    write_transforms,
)
from gsslam.types import CameraIntrinsics


def test_round_trip_and_opengl_axes(tmp_path):
    rng = np.random.default_rng(3)
    intr = CameraIntrinsics(535.4, 539.2, 320.1, 247.6, 640, 480)
    frames = [
        NerfstudioFrame(f"images/{k}.jpg", make_T(so3_exp(rng.normal(size=3)), rng.normal(size=3)))
        for k in range(5)
    ]
    write_transforms(tmp_path / "transforms.json", intr, frames, {"gsslam_units": "metres"})
    data = json.loads((tmp_path / "transforms.json").read_text())
    assert (data["fl_x"], data["cy"], data["w"], data["h"]) == (535.4, 247.6, 640, 480)
    M = np.array(data["frames"][0]["transform_matrix"])
    T = frames[0].T_world_cam
    # OpenGL: the camera looks along -z, so the viewing direction (OpenCV +z) is -M[:, 2]; y is flipped
    np.testing.assert_allclose(-M[:3, 2], T[:3, 2], atol=1e-12)
    np.testing.assert_allclose(-M[:3, 1], T[:3, 1], atol=1e-12)
    np.testing.assert_allclose(M[:3, 3], T[:3, 3], atol=1e-12)
    intr2, back, extra = read_transforms(tmp_path / "transforms.json")
    assert intr2 == intr and extra["gsslam_units"] == "metres"
    for a, b in zip(back, frames):
        assert a.file_path == b.file_path
        np.testing.assert_allclose(a.T_world_cam, b.T_world_cam, atol=1e-15)


def test_errors_are_typed(tmp_path):
    with pytest.raises(NerfstudioError, match="not found"):
        read_transforms(tmp_path / "x.json")
    with pytest.raises(NerfstudioError, match="fl_x"):
        parse_transforms('{"frames": []}')
    with pytest.raises(NerfstudioError, match="frame 0"):
        parse_transforms('{"fl_x":1,"fl_y":1,"cx":1,"cy":1,"w":2,"h":2,"frames":[{"file_path":"a"}]}')
