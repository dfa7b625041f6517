"""Malformed input files are refused before any work, as one line naming the file and the fix.

Each case runs ``python -m gsslam`` on a broken copy of the bundled data (issue #14)."""

from __future__ import annotations

import shutil

import cv2
import numpy as np
import pytest
import yaml
from reliability_helpers import (
    assert_error,
    edit_row,
    gsslam,
    list_files,
    sevenscenes_from_teddy,
    snapshot,
    teddy_copy,
)

from gsslam.io.ply import GaussianPly, write_ply

FAST = ("--max-frames", "10", "--set", "mapper.enabled=false", "--no-progress")


@pytest.mark.parametrize("bad", ["nan", "inf"])
def test_non_finite_groundtruth_is_refused_when_opened(tmp_path, bad):
    seq = teddy_copy(tmp_path)
    edit_row(seq / "groundtruth.txt", 4, lambda f: [f[0], bad, *f[2:]])
    before = snapshot(seq)
    r = gsslam("run", seq, "--out", tmp_path / "out", *FAST)
    assert_error(r, "groundtruth.txt:8:", "non-finite", "fix the file or delete that row")
    assert not (tmp_path / "out").exists()  # refused before the run: nothing written
    assert snapshot(seq) == before


def test_zero_quaternion_in_groundtruth(tmp_path):
    seq = teddy_copy(tmp_path)
    edit_row(seq / "groundtruth.txt", 2, lambda f: [*f[:4], "0", "0", "0", "0"])
    assert_error(gsslam("run", seq, "--out", tmp_path / "out", *FAST), "groundtruth.txt:6:", "quaternion")


def test_eight_bit_depth_png_is_refused(tmp_path):
    seq = teddy_copy(tmp_path)
    depth = list_files(seq, "depth.txt")[7]
    raw = cv2.imread(str(depth), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(depth), (raw // 256).astype(np.uint8))  # what an 8-bit export does
    r = gsslam("run", seq, "--mode", "rgbd", "--out", tmp_path / "out", *FAST)
    assert_error(r, str(depth), "8-bit", "16-bit")
    assert not (tmp_path / "out").exists()


def test_odd_sized_image_is_refused_before_the_run(tmp_path):
    seq = teddy_copy(tmp_path)
    odd = list_files(seq, "rgb.txt")[9]
    cv2.imwrite(str(odd), cv2.resize(cv2.imread(str(odd)), (320, 240)))
    r = gsslam("run", seq, "--out", tmp_path / "out", *FAST)
    assert_error(r, str(odd), "320x240", "640x480")
    assert not (tmp_path / "out").exists()


def test_images_dataset_with_mixed_sizes(tmp_path):
    seq = teddy_copy(tmp_path)
    folder = tmp_path / "imgs"
    folder.mkdir()
    for i, f in enumerate(list_files(seq, "rgb.txt")):
        shutil.copy(f, folder / f"img_{i:03d}.png")
    odd = folder / "img_008.png"
    cv2.imwrite(str(odd), cv2.resize(cv2.imread(str(odd)), (320, 240)))
    intr = tmp_path / "intrinsics.yaml"
    intr.write_text(yaml.safe_dump({"fx": 535.4, "fy": 539.2, "cx": 320.1, "cy": 247.6}))
    r = gsslam("run", folder, "--dataset", "images", "--intrinsics", intr, "--out", tmp_path / "out", *FAST)
    assert_error(r, str(odd), "320x240", "img_000.png is 640x480")
    assert not (tmp_path / "out").exists()


def test_corrupt_image_is_refused_before_the_run(tmp_path):
    seq = teddy_copy(tmp_path)
    bad = list_files(seq, "rgb.txt")[5]
    bad.write_bytes(b"\x89PNG\r\n\x1a\n not really")
    assert_error(
        gsslam("run", seq, "--out", tmp_path / "out", *FAST), str(bad), "corrupt", "replace the file"
    )


@pytest.mark.parametrize(
    "content, message",
    [
        (bytes(range(256)) * 8, "not a text file"),
        (b"fx: [1, 2\n", "not valid YAML"),
        (b"- 1\n- 2\n", "must be a YAML mapping"),
        (b"fx: 0\nfy: 500\ncx: 320\ncy: 240\n", "focal lengths must be positive"),
    ],
)
def test_bad_intrinsics_yaml(tmp_path, content, message):
    seq = teddy_copy(tmp_path)
    folder = tmp_path / "imgs"
    folder.mkdir()
    shutil.copy(list_files(seq, "rgb.txt")[0], folder / "a.png")
    intr = tmp_path / "intrinsics.yaml"
    intr.write_bytes(content)
    r = gsslam("run", folder, "--dataset", "images", "--intrinsics", intr, "--out", tmp_path / "out", *FAST)
    assert_error(r, str(intr), message)


def test_malformed_sevenscenes_pose_is_refused_when_opened(tmp_path):
    seq = sevenscenes_from_teddy(tmp_path)
    bad = seq / "frame-000003.pose.txt"
    bad.write_text("1 0 0 0\n0 1 0 0\n0 0 1\n")
    r = gsslam("run", seq, "--dataset", "7scenes", "--out", tmp_path / "out", *FAST)
    assert_error(r, str(bad), "4x4", "delete it")
    assert not (tmp_path / "out").exists()


def test_render_refuses_a_corrupt_run_folder(tmp_path):
    run = tmp_path / "run"
    n = 20
    rng = np.random.default_rng(0)
    write_ply(
        run / "map.ply",
        GaussianPly(
            rng.normal(size=(n, 3)) + [0, 0, 3],
            np.tile([1.0, 0, 0, 0], (n, 1)),
            np.full((n, 3), -3.0),
            np.zeros(n),
            np.zeros((n, 3)),
        ),  # fmt: skip
    )
    (run / "trajectory.tum").write_text("0.0 0 0 0 0 0 0 1\n1.0 0 0 0 0 0 0 1\n")
    (run / "intrinsics.yaml").write_text(
        yaml.safe_dump({"fx": 100.0, "fy": 100.0, "cx": 32.0, "cy": 24.0, "width": 64, "height": 48})
    )
    (run / "config.yaml").write_bytes(b"\x00\xff\xfe garbage \x9c")
    assert_error(gsslam("render", run, "--out", tmp_path / "r"), str(run / "config.yaml"), "not a text file")
    (run / "config.yaml").write_text("mapper: {max_side: -4}\n")
    assert_error(gsslam("render", run, "--out", tmp_path / "r"), "mapper.max_side", ">= 16")
    (run / "config.yaml").write_text("mapper: {max_side: 64}\n")
    (run / "intrinsics.yaml").write_bytes(b"\xff\xfe\x00")
    assert_error(gsslam("render", run, "--out", tmp_path / "r"), "intrinsics.yaml", "not a valid intrinsics")
    (run / "intrinsics.yaml").write_text(
        yaml.safe_dump({"fx": 100.0, "fy": 100.0, "cx": 32.0, "cy": 24.0, "width": 64, "height": 48})
    )
    (run / "trajectory.tum").write_text("0.0 0 0 0 0 0 0 1\n1.0 0 zero 0 0 0 0 1\n")
    assert_error(gsslam("render", run, "--out", tmp_path / "r"), "trajectory.tum:2", "not a number")
    (run / "trajectory.tum").write_text("0.0 0 0 0 0 0 0 1\n")
    r = gsslam("render", run, "--out", tmp_path / "r", "--every", "1")
    assert r.returncode == 0, r.stderr
    assert len(list((tmp_path / "r").glob("*.png"))) == 1
