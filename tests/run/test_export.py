"""`gsslam export` on a run folder: every format, read back by real readers, units stated."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gsslam.io.colmap import read_colmap_text
from gsslam.io.inria import inria_property_names, read_ply_property_names
from gsslam.io.nerfstudio import read_transforms
from gsslam.io.ply import read_ply
from gsslam.io.trajectory import read_tum
from gsslam.run.export import ExportError, export_run
from helpers.run_folder import make_run


def test_colmap_export_with_images(tmp_path):
    run = make_run(tmp_path / "run")
    out = export_run(run, "colmap", tmp_path / "colmap", images=True)
    kf = read_tum(run / "keyframes.tum")
    model = read_colmap_text(out / "sparse" / "0")
    assert len(model.images) == len(kf)
    for im, T in zip(model.images, kf.poses):
        np.testing.assert_allclose(im.T_world_cam, T, atol=1e-12)
        assert (out / "images" / im.name).is_file()
    g = read_ply(run / "map.ply")
    np.testing.assert_allclose(model.points_xyz, g.means, atol=1e-7)
    assert "units: metres" in (out / "README.txt").read_text()
    pycolmap = pytest.importorskip("pycolmap", reason="pycolmap (dev extra) reads the model as COLMAP does")
    rec = pycolmap.Reconstruction(str(out / "sparse" / "0"))
    for im, T in zip(model.images, kf.poses):
        np.testing.assert_allclose(rec.find_image_with_name(im.name).projection_center(), T[:3, 3], atol=1e-9)


def test_nerfstudio_export_round_trips_poses(tmp_path):
    run = make_run(tmp_path / "run", mode="mono")
    out = export_run(run, "nerfstudio", tmp_path / "ns", images=True)
    intr, frames, extra = read_transforms(out / "transforms.json")
    kf = read_tum(run / "keyframes.tum")
    assert (intr.width, intr.height) == (64, 48)
    assert extra["gsslam_units"].startswith("arbitrary") and extra["ply_file_path"] == "sparse_pc.ply"
    for f, T in zip(frames, kf.poses):
        np.testing.assert_allclose(f.T_world_cam, T, atol=1e-12)
        assert (out / f.file_path).is_file()
    assert "arbitrary" in (out / "README.txt").read_text()


def test_inria_export(tmp_path):
    run = make_run(tmp_path / "run")
    out = export_run(run, "inria", tmp_path / "inria", images=True, sh_degree=3, iteration=30000)
    ply = out / "point_cloud" / "iteration_30000" / "point_cloud.ply"
    assert read_ply_property_names(ply) == inria_property_names(3)
    assert len(json.loads((out / "cameras.json").read_text())) == 5
    assert (out / "sparse" / "0" / "images.txt").is_file() and (out / "images").is_dir()
    assert f"source_path={str(out.resolve())!r}" in (out / "cfg_args").read_text()


def test_missing_images_and_bad_format_are_actionable(tmp_path):
    run = make_run(tmp_path / "run")
    for p in (run / "keyframes").iterdir():
        p.unlink()
    with pytest.raises(ExportError, match="re-run"):
        export_run(run, "colmap", tmp_path / "c", images=True)
    export_run(run, "colmap", tmp_path / "c2")  # without --images the model alone is fine
    with pytest.raises(ExportError, match="colmap, nerfstudio, inria"):
        export_run(run, "ply", tmp_path / "x")
    with pytest.raises(ExportError, match="0..3"):
        export_run(run, "inria", tmp_path / "x", sh_degree=4)
    (run / "map.ply").unlink()
    with pytest.raises(ExportError, match="map.ply"):
        export_run(run, "inria", tmp_path / "i")


def test_cli_export(tmp_path):
    from typer.testing import CliRunner

    from gsslam.cli import app

    run = make_run(tmp_path / "run")
    res = CliRunner().invoke(
        app, ["export", str(run), "--format", "nerfstudio", "--out", str(tmp_path / "o")]
    )
    assert res.exit_code == 0, res.output
    assert (tmp_path / "o" / "transforms.json").is_file()
