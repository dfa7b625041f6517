"""`--dataset rosbag`: bags written from the bundled TUM frames read back as the same frames, and a
run on the bag gives the same trajectory file as a run on the folder."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from gsslam.datasets.base import open_dataset
from gsslam.datasets.tum import TumRgbdDataset

pytest.importorskip("rosbags", reason="rosbags (extra 'ros', in dev) reads and writes the bags")
from gsslam.datasets.rosbag import RosbagError  # noqa: E402
from helpers.bags import write_bag  # noqa: E402

N = 24


@pytest.fixture(scope="module")
def tum_frames(bundled_tum):
    ds = TumRgbdDataset(bundled_tum)
    return ds, [ds[i] for i in range(N)]


@pytest.fixture(scope="module")
def ros1_bag(tum_frames, tmp_path_factory):
    return write_bag(tmp_path_factory.mktemp("bag") / "teddy.bag", tum_frames[1], "ros1")


@pytest.mark.parametrize("kind,compressed", [("ros1", False), ("mcap", False), ("mcap", True)])
def test_bag_frames_equal_the_folder_frames(tum_frames, tmp_path, kind, compressed):
    ds, frames = tum_frames
    path = write_bag(tmp_path / ("b.bag" if kind == "ros1" else "b"), frames[:6], kind, compressed)
    bag = open_dataset("rosbag", path)  # topics, depth and camera_info picked automatically
    assert len(bag) == 6 and bag.has_depth
    assert bag.timestamps() == ds.timestamps()[:6]  # bit-identical float64 stamps
    assert bag.intrinsics == ds.intrinsics
    for i in range(6):
        a, b = bag[i], frames[i]
        np.testing.assert_array_equal(a.image, b.image)
        np.testing.assert_array_equal(a.depth, b.depth)  # NaN where invalid, as the TUM loader
    t, gyro, acc = bag.imu()
    assert len(t) == 6 and gyro[1, 0] == pytest.approx(0.1) and acc[0, 2] == pytest.approx(9.81)
    if kind == "mcap":  # a single .mcap file opens as well as the ROS2 bag folder
        single = open_dataset("rosbag", next(path.glob("*.mcap")), with_depth=False)
        assert len(single) == 6 and not single.has_depth


def test_run_on_bag_gives_the_same_trajectory_as_on_the_folder(bundled_tum, ros1_bag, tmp_path):
    pytest.importorskip("gsslam.graph.submap_graph")
    from gsslam.config import load_config
    from gsslam.run.sequence import run_sequence

    cfg = load_config(None, ["mapper.enabled=false", "loop.enabled=false"], mode="rgbd")
    run_sequence(bundled_tum, "tum", cfg, tmp_path / "folder", max_frames=N, progress=False)
    gt = bundled_tum / "groundtruth.txt"
    run_sequence(ros1_bag, "rosbag", cfg, tmp_path / "bag", progress=False, gt_path=gt)
    for name in ("trajectory.tum", "keyframes.tum"):
        assert (tmp_path / "bag" / name).read_text() == (tmp_path / "folder" / name).read_text(), name
    # the runner keeps one image per keyframe, named by its timestamp, for exports
    n_kf = sum(1 for line in (tmp_path / "bag" / "keyframes.tum").read_text().splitlines() if line[0] != "#")
    assert len(list((tmp_path / "bag" / "keyframes").glob("*.jpg"))) == n_kf > 0
    # ... and its camera, so that a run without a map still exports its keyframe cameras
    from gsslam.io.colmap import read_colmap_text
    from gsslam.run.export import export_run

    model = read_colmap_text(export_run(tmp_path / "bag", "colmap", images=True) / "sparse" / "0")
    assert len(model.images) == n_kf and len(model.points_xyz) == 0


def test_topic_choice_and_errors(tum_frames, ros1_bag, tmp_path):
    bag = open_dataset("rosbag", ros1_bag, image_topic="/camera/rgb/image_color", with_depth=False)
    assert not bag.has_depth and len(bag) == N
    with pytest.raises(RosbagError, match="no topic '/nope'"):
        open_dataset("rosbag", ros1_bag, image_topic="/nope")
    two = write_bag(tmp_path / "two.bag", tum_frames[1][:2], "ros1", depth_topic="/camera/aligned/image")
    with pytest.raises(
        RosbagError, match="found /camera/aligned/image, /camera/rgb/image_color; pass image_topic="
    ):
        open_dataset("rosbag", two)
    assert not open_dataset(
        "rosbag", two, image_topic="/camera/rgb/image_color"
    ).has_depth  # no 'depth' topic
    k = yaml.safe_dump({"fx": 500.0, "fy": 500.0, "cx": 320.0, "cy": 240.0, "width": 640, "height": 480})
    (tmp_path / "k.yaml").write_text(k)
    bag = open_dataset("rosbag", ros1_bag, intrinsics_file=tmp_path / "k.yaml")
    assert bag.intrinsics.fx == 500.0
    (tmp_path / "bad.bag").write_bytes(b"not a bag")
    with pytest.raises(RosbagError, match="cannot open"):
        open_dataset("rosbag", tmp_path / "bad.bag")
