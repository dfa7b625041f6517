"""INRIA 3DGS model folders: the exact PLY property list its loader asserts, cameras.json, cfg_args."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gsslam.geometry import make_T, so3_exp
from gsslam.io.inria import (
    InriaCamera,
    InriaError,
    inria_property_names,
    n_rest,
    read_ply_property_names,
    with_sh_degree,
    write_inria_model,
)
from gsslam.io.ply import GaussianPly, read_ply
from gsslam.types import CameraIntrinsics


def _g(n=30, m=0, seed=0):
    rng = np.random.default_rng(seed)
    return GaussianPly(
        rng.normal(size=(n, 3)), np.tile([1.0, 0, 0, 0], (n, 1)), rng.normal(size=(n, 3)),
        rng.normal(size=n), rng.normal(size=(n, 3)), rng.normal(size=(n, m)),
    )  # fmt: skip


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_ply_has_exactly_the_properties_the_inria_loader_asserts(tmp_path, degree):
    g = _g()
    cams = [
        InriaCamera(
            "a.jpg",
            make_T(so3_exp(np.array([0.1, 0.2, 0.3])), np.ones(3)),
            CameraIntrinsics(500, 501, 320, 240, 640, 480),
        )
    ]
    ply = write_inria_model(tmp_path, g, cams, sh_degree=degree, iteration=7000)
    assert ply == tmp_path / "point_cloud" / "iteration_7000" / "point_cloud.ply"
    names = read_ply_property_names(ply)
    # the loader: len(f_rest_*) == 3 * (max_sh_degree + 1) ** 2 - 3, in this order
    expected = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    expected += [f"f_rest_{i}" for i in range(3 * (degree + 1) ** 2 - 3)]
    expected += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    assert names == expected == inria_property_names(degree)
    back = read_ply(ply)
    np.testing.assert_array_equal(back.means, g.means)
    np.testing.assert_array_equal(back.f_rest, np.zeros((len(g), n_rest(degree))))
    cam = json.loads((tmp_path / "cameras.json").read_text())[0]
    assert cam["img_name"] == "a" and cam["fx"] == 500 and cam["width"] == 640
    np.testing.assert_allclose(cam["position"], np.ones(3))
    np.testing.assert_allclose(cam["rotation"], cams[0].T_world_cam[:3, :3])
    cfg = (tmp_path / "cfg_args").read_text()
    assert cfg.startswith("Namespace(") and f"sh_degree={degree}," in cfg


def test_sh_resize_pads_and_truncates_per_channel():
    g = _g(n=4, m=n_rest(1))  # 3 coefficients per channel
    up = with_sh_degree(g, 2)  # 8 per channel
    r_in, r_out = g.f_rest.reshape(4, 3, 3), up.f_rest.reshape(4, 3, 8)
    np.testing.assert_array_equal(r_out[:, :, :3], r_in)
    assert not r_out[:, :, 3:].any()
    down = with_sh_degree(up, 1)
    np.testing.assert_array_equal(down.f_rest, g.f_rest)
    with pytest.raises(InriaError, match="0..3"):
        with_sh_degree(g, 4)
