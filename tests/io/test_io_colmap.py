"""COLMAP text models: our round trip, pycolmap reading what we write, typed errors."""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.geometry import make_T, so3_exp
from gsslam.io.colmap import (
    ColmapCamera,
    ColmapError,
    ColmapImage,
    ColmapModel,
    pose_from_colmap,
    pose_to_colmap,
    read_colmap_text,
    write_colmap_text,
)


def _model(n: int = 6, seed: int = 0) -> ColmapModel:
    rng = np.random.default_rng(seed)
    poses = [make_T(so3_exp(rng.normal(size=3)), rng.normal(size=3) * 2) for _ in range(n)]
    return ColmapModel(
        [ColmapCamera(1, "PINHOLE", 640, 480, (535.4, 539.2, 320.1, 247.6))],
        [ColmapImage(k + 1, f"{k:04d}.jpg", 1, T) for k, T in enumerate(poses)],
        rng.normal(size=(50, 3)),
        rng.integers(0, 256, (50, 3)),
    )


def test_pose_conversion_is_world_to_camera_wxyz():
    T = make_T(so3_exp(np.array([0.3, -0.2, 0.5])), np.array([1.0, 2.0, 3.0]))
    q, t = pose_to_colmap(T)
    # COLMAP stores X_cam = R X_world + t: the camera centre maps to the origin
    R_cw = np.linalg.inv(T)[:3, :3]
    np.testing.assert_allclose(R_cw @ T[:3, 3] + t, 0, atol=1e-12)
    assert q[0] >= 0 and abs(np.linalg.norm(q) - 1) < 1e-12
    np.testing.assert_allclose(pose_from_colmap(q, t), T, atol=1e-12)


def test_round_trip_through_our_reader(tmp_path):
    m = _model()
    write_colmap_text(m, tmp_path, comment="units: metres")
    back = read_colmap_text(tmp_path)
    assert back.cameras == m.cameras
    assert [i.name for i in back.images] == [i.name for i in m.images]
    for a, b in zip(back.images, m.images):
        np.testing.assert_allclose(a.T_world_cam, b.T_world_cam, atol=1e-12)
    np.testing.assert_array_equal(back.points_xyz, m.points_xyz)
    np.testing.assert_array_equal(back.points_rgb, m.points_rgb)
    assert "# units: metres" in (tmp_path / "images.txt").read_text()


def test_pycolmap_reads_the_model_with_the_same_poses(tmp_path):
    pycolmap = pytest.importorskip(
        "pycolmap", reason="pycolmap (dev extra) checks the files with COLMAP's reader"
    )
    m = _model()
    write_colmap_text(m, tmp_path)
    rec = pycolmap.Reconstruction(str(tmp_path))
    assert rec.num_cameras() == 1 and rec.num_images() == len(m.images) and rec.num_points3D() == 50
    cam = rec.cameras[1]
    assert (cam.model.name, cam.width, cam.height) == ("PINHOLE", 640, 480)
    np.testing.assert_allclose(cam.params, m.cameras[0].params)
    for im in m.images:
        got = rec.find_image_with_name(im.name)
        cfw = got.cam_from_world()  # Rigid3d: T_cam_world
        np.testing.assert_allclose(cfw.matrix(), np.linalg.inv(im.T_world_cam)[:3], atol=1e-9)
        np.testing.assert_allclose(got.projection_center(), im.T_world_cam[:3, 3], atol=1e-9)
    xyz = np.array([p.xyz for p in rec.points3D.values()])
    rgb = np.array([p.color for p in rec.points3D.values()])
    order = np.lexsort(xyz.T)
    ref = np.lexsort(m.points_xyz.T)
    np.testing.assert_allclose(xyz[order], m.points_xyz[ref])
    np.testing.assert_array_equal(rgb[order], m.points_rgb[ref])


def test_errors_are_typed(tmp_path):
    m = _model()
    m.images[0].name = "has space.jpg"
    with pytest.raises(ColmapError, match="without spaces"):
        write_colmap_text(m, tmp_path)
    m = _model()
    m.images[0].camera_id = 7
    with pytest.raises(ColmapError, match="camera 7"):
        write_colmap_text(m, tmp_path)
    with pytest.raises(ColmapError, match="not found"):
        read_colmap_text(tmp_path / "nothing")
    write_colmap_text(_model(), tmp_path)
    (tmp_path / "cameras.txt").write_text("1 PINHOLE 640 480 1 2 3\n")
    with pytest.raises(ColmapError, match="cameras.txt:1"):
        read_colmap_text(tmp_path)
