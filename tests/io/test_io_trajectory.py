"""TUM / KITTI trajectory files: round trips (in memory and on disk) and typed errors."""

from __future__ import annotations

import numpy as np
import pytest

from gsslam.geometry import make_T, quat_to_rot, so3_exp
from gsslam.io.trajectory import (
    TrajectoryIOError,
    format_kitti,
    format_tum,
    parse_kitti,
    parse_tum,
    read_kitti,
    read_trajectory,
    read_tum,
    write_kitti,
    write_trajectory,
    write_tum,
)
from gsslam.types import Trajectory


def _random_traj(n: int, rng: np.random.Generator, t0: float = 1341841873.4151) -> Trajectory:
    stamps = t0 + np.cumsum(rng.uniform(0.01, 0.05, n))  # arbitrary float64 digits, not 4 decimals
    poses = np.stack([make_T(so3_exp(rng.normal(size=3)), rng.normal(size=3) * 3) for _ in range(n)])
    return Trajectory(stamps, poses)


def test_tum_in_memory_round_trip_keeps_full_precision():
    traj = _random_traj(50, np.random.default_rng(1))
    back = parse_tum(format_tum(traj))
    np.testing.assert_array_equal(back.timestamps, traj.timestamps)  # bit-identical
    np.testing.assert_array_equal(back.positions, traj.positions)
    np.testing.assert_allclose(back.poses[:, :3, :3], traj.poses[:, :3, :3], atol=1e-14)
    # A second round trip moves nothing but the last bits of the rotations.
    again = parse_tum(format_tum(back))
    np.testing.assert_array_equal(again.timestamps, traj.timestamps)
    np.testing.assert_allclose(again.poses, traj.poses, atol=1e-14, rtol=0)


def test_tum_file_round_trip_small_and_large_timestamps(tmp_path):
    rng = np.random.default_rng(2)
    for t0 in (0.0, 1e-7, 1.7e9, 1403715273262142976e-9):
        traj = _random_traj(10, rng, t0=t0)
        p = tmp_path / "t.tum"
        write_tum(traj, p)
        text = p.read_text()
        assert "e" not in text.splitlines()[1].split()[0]  # timestamps never in scientific notation
        back = read_tum(p)
        np.testing.assert_array_equal(back.timestamps, traj.timestamps)
        np.testing.assert_array_equal(back.positions, traj.positions)


def test_tum_reads_real_teddy_ground_truth(bundled_tum):
    gt = read_tum(bundled_tum / "groundtruth.txt")
    assert len(gt) == 234  # 237 lines minus 3 comment lines
    assert gt.timestamps[0] == 1341841873.4151
    np.testing.assert_array_equal(gt.positions[0], [-2.1837, 0.6821, 1.4854])
    np.testing.assert_allclose(gt.poses[0, :3, :3], quat_to_rot(np.array([-0.2651, 0.7889, -0.5183, 0.1970])))
    R = gt.poses[:, :3, :3]
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)


def test_tum_write_rejects_sim3_poses():
    traj = Trajectory([0.0], make_T(np.eye(3), np.zeros(3), 2.0)[None])
    with pytest.raises(TrajectoryIOError, match="rigid"):
        format_tum(traj)


@pytest.mark.parametrize(
    "line, match",
    [
        ("1.0 2 3 4 0 0 0", "expected 8 numbers"),
        ("1.0 2 3 4 0 0 0 1 9", "expected 8 numbers"),
        ("1.0 2 3 x 0 0 0 1", "not a number"),
        ("1.0 2 3 nan 0 0 0 1", "non-finite"),
        ("1.0 2 3 4 0 0 0 0", "zero norm"),
    ],
)
def test_tum_malformed_line_names_file_and_line(tmp_path, line, match):
    p = tmp_path / "bad.tum"
    p.write_text("# header\n0.5 0 0 0 0 0 0 1\n\n" + line + "\n")
    with pytest.raises(TrajectoryIOError, match=match) as e:
        read_tum(p)
    assert f"{p}:4:" in str(e.value)


def test_missing_and_empty_files(tmp_path):
    with pytest.raises(TrajectoryIOError, match="not found"):
        read_tum(tmp_path / "nope.txt")
    (tmp_path / "empty.txt").write_text("# only a comment\n")
    with pytest.raises(TrajectoryIOError, match="no poses"):
        read_tum(tmp_path / "empty.txt")
    with pytest.raises(TrajectoryIOError, match="unknown trajectory format"):
        read_trajectory(tmp_path / "empty.txt", "euroc")


def test_kitti_round_trip_and_index_timestamps(tmp_path):
    traj = _random_traj(20, np.random.default_rng(3))
    back = parse_kitti(format_kitti(traj))
    np.testing.assert_array_equal(back.poses, traj.poses)  # the 3x4 block is stored verbatim
    np.testing.assert_array_equal(back.timestamps, np.arange(20.0))
    write_kitti(traj, tmp_path / "p.txt", times_path=tmp_path / "times.txt")
    back = read_kitti(tmp_path / "p.txt", tmp_path / "times.txt")
    np.testing.assert_array_equal(back.timestamps, traj.timestamps)
    np.testing.assert_array_equal(back.poses, traj.poses)
    write_trajectory(traj, tmp_path / "q.txt", "kitti")
    np.testing.assert_array_equal(read_trajectory(tmp_path / "q.txt", "kitti").poses, traj.poses)


def test_kitti_errors(tmp_path):
    p = tmp_path / "k.txt"
    p.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1\n")
    with pytest.raises(TrajectoryIOError, match=rf"{p}:2: expected 12 numbers"):
        read_kitti(p)
    p.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n")
    (tmp_path / "times.txt").write_text("0.0\n0.1\n")
    with pytest.raises(TrajectoryIOError, match="1 poses but 2 timestamps"):
        read_kitti(p, tmp_path / "times.txt")


def test_kitti_reads_real_poses_and_times(shared_data):
    root = shared_data / "kitti_odometry"
    traj = read_kitti(root / "poses" / "06.txt", root / "sequences" / "06" / "times.txt")
    assert len(traj) == 1101
    assert traj.timestamps[1] == 1.044989e-01
    np.testing.assert_allclose(traj.positions[1], [-1.401751e-02, -2.820321e-02, 1.198998e00])
    back = parse_kitti(format_kitti(traj), timestamps=traj.timestamps)
    np.testing.assert_array_equal(back.poses, traj.poses)
