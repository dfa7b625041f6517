"""Trajectory files: TUM (``timestamp tx ty tz qx qy qz qw``) and KITTI (12 numbers per line).

Both hold camera poses ``T_world_cam`` (camera-to-world). TUM quaternions are (qx, qy, qz, qw).
KITTI pose files have no timestamps: frame ``i`` gets timestamp ``i`` (seconds), unless a times
file (one timestamp per line, KITTI's ``times.txt``) is given.

Numbers are written with the shortest decimal that reads back to the same float64, so timestamps,
translations and KITTI matrices keep every bit through a round trip (timestamps are written
positionally, never in scientific notation); TUM rotations pass through a quaternion (~1e-15).
``parse_*`` / ``format_*`` work on strings (in-memory round trips); ``read_*`` / ``write_*`` on files.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np

from gsslam.errors import GsslamError
from gsslam.geometry import quat_to_rot, rot_to_quat
from gsslam.io.atomic import atomic_write_text
from gsslam.types import Trajectory

_log = logging.getLogger(__name__)

FORMATS = ("tum", "kitti")


class TrajectoryIOError(GsslamError):
    """A trajectory file is missing, malformed, or a trajectory cannot be written in a format."""


def _fmt_time(t: float) -> str:
    return np.format_float_positional(float(t), unique=True, trim="-")


def _fmt_value(v: float) -> str:
    return repr(float(v))


def _numbers(line: str, source: str, lineno: int, expected: int, what: str) -> list[float]:
    fields = line.replace(",", " ").split()
    if len(fields) != expected:
        raise TrajectoryIOError(
            f"{source}:{lineno}: expected {expected} numbers ({what}), got {len(fields)}: {line.strip()!r}"
        )
    try:
        values = [float(f) for f in fields]
    except ValueError:
        raise TrajectoryIOError(f"{source}:{lineno}: not a number in {line.strip()!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise TrajectoryIOError(f"{source}:{lineno}: non-finite value in {line.strip()!r}")
    return values


def _data_lines(text: str) -> list[tuple[int, str]]:
    """(1-based line number, line) for every non-empty line that is not a '#' comment."""
    out = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if s and not s.startswith("#"):
            out.append((lineno, s))
    return out


def _read_text(path: str | Path) -> str:
    p = Path(path)
    if not p.is_file():
        raise TrajectoryIOError(f"trajectory file not found: {p}")
    try:
        return p.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise TrajectoryIOError(f"cannot read trajectory file {p}: {e}") from None


# ---------------------------------------------------------------------------------------------- TUM


def parse_tum(text: str, source: str = "<string>") -> Trajectory:
    """Parse TUM text: one ``timestamp tx ty tz qx qy qz qw`` per line, '#' comments, blank lines."""
    stamps, poses = [], []
    for lineno, line in _data_lines(text):
        t, tx, ty, tz, qx, qy, qz, qw = _numbers(line, source, lineno, 8, "timestamp tx ty tz qx qy qz qw")
        q = np.array([qx, qy, qz, qw])
        norm = float(np.linalg.norm(q))
        if norm < 1e-6:
            raise TrajectoryIOError(f"{source}:{lineno}: quaternion (qx qy qz qw) has zero norm")
        if abs(norm - 1.0) > 1e-3:
            _log.debug("%s:%d: quaternion norm %.6f, normalising", source, lineno, norm)
        T = np.eye(4)
        T[:3, :3] = quat_to_rot(q)
        T[:3, 3] = (tx, ty, tz)
        stamps.append(t)
        poses.append(T)
    if not poses:
        raise TrajectoryIOError(f"{source}: no poses found (expected lines 'timestamp tx ty tz qx qy qz qw')")
    return Trajectory(np.array(stamps), np.stack(poses), meta={"source": source, "format": "tum"})


def format_tum(traj: Trajectory, header: str | None = "timestamp tx ty tz qx qy qz qw") -> str:
    """TUM text of ``traj`` (poses must be rigid: a Sim(3) scale cannot be stored in a quaternion)."""
    R = traj.poses[:, :3, :3]
    dets = np.linalg.det(R)
    if len(R) and np.max(np.abs(dets - 1.0)) > 1e-4:  # KITTI files carry ~7 digits
        i = int(np.argmax(np.abs(dets - 1.0)))
        raise TrajectoryIOError(
            f"pose {i} has a rotation block with determinant {dets[i]:.6g}; TUM files hold rigid poses "
            "only (apply any Sim(3) scale to the translations first)"
        )
    quats = rot_to_quat(R) if len(R) else np.zeros((0, 4))
    lines = [f"# {header}"] if header else []
    for t, T, q in zip(traj.timestamps, traj.poses, quats):
        vals = " ".join(_fmt_value(v) for v in (*T[:3, 3], *q))
        lines.append(f"{_fmt_time(t)} {vals}")
    return "\n".join(lines) + "\n"


def read_tum(path: str | Path) -> Trajectory:
    return parse_tum(_read_text(path), source=str(path))


def write_tum(traj: Trajectory, path: str | Path) -> None:
    atomic_write_text(path, format_tum(traj))


# -------------------------------------------------------------------------------------------- KITTI


def parse_kitti(text: str, source: str = "<string>", timestamps: np.ndarray | None = None) -> Trajectory:
    """Parse KITTI poses: 12 numbers per line, the row-major 3x4 ``[R | t]`` of ``T_world_cam``.

    ``timestamps`` [N] (e.g. from :func:`parse_times`); default: the frame index.
    """
    poses = []
    for lineno, line in _data_lines(text):
        v = _numbers(line, source, lineno, 12, "row-major 3x4 pose")
        T = np.eye(4)
        T[:3, :] = np.array(v).reshape(3, 4)
        poses.append(T)
    if not poses:
        raise TrajectoryIOError(f"{source}: no poses found (expected 12 numbers per line)")
    if timestamps is None:
        stamps = np.arange(len(poses), dtype=np.float64)
    else:
        stamps = np.asarray(timestamps, dtype=np.float64).reshape(-1)
        if len(stamps) != len(poses):
            raise TrajectoryIOError(
                f"{source}: {len(poses)} poses but {len(stamps)} timestamps; the times file must have "
                "one line per pose"
            )
    return Trajectory(stamps, np.stack(poses), meta={"source": source, "format": "kitti"})


def format_kitti(traj: Trajectory) -> str:
    lines = [" ".join(_fmt_value(v) for v in T[:3, :].reshape(-1)) for T in traj.poses]
    return "\n".join(lines) + "\n"


def parse_times(text: str, source: str = "<string>") -> np.ndarray:  # -> [N] float64 seconds
    """One timestamp per line (KITTI ``times.txt``)."""
    return np.array([_numbers(line, source, n, 1, "timestamp")[0] for n, line in _data_lines(text)])


def format_times(timestamps: np.ndarray) -> str:  # timestamps [N]
    return "".join(f"{_fmt_time(t)}\n" for t in np.asarray(timestamps).reshape(-1))


def read_kitti(path: str | Path, times_path: str | Path | None = None) -> Trajectory:
    stamps = None if times_path is None else parse_times(_read_text(times_path), source=str(times_path))
    return parse_kitti(_read_text(path), source=str(path), timestamps=stamps)


def write_kitti(traj: Trajectory, path: str | Path, times_path: str | Path | None = None) -> None:
    atomic_write_text(path, format_kitti(traj))
    if times_path is not None:
        atomic_write_text(times_path, format_times(traj.timestamps))


# ------------------------------------------------------------------------------------------ dispatch


def read_trajectory(path: str | Path, fmt: str = "tum", times_path: str | Path | None = None) -> Trajectory:
    """Read a trajectory file in format ``fmt`` ('tum' or 'kitti')."""
    if fmt == "tum":
        if times_path is not None:
            raise TrajectoryIOError("a times file is for KITTI files only; TUM lines hold timestamps")
        return read_tum(path)
    if fmt == "kitti":
        return read_kitti(path, times_path)
    raise TrajectoryIOError(f"unknown trajectory format {fmt!r}; choose one of: {', '.join(FORMATS)}")


def write_trajectory(traj: Trajectory, path: str | Path, fmt: str = "tum") -> None:
    if fmt == "tum":
        write_tum(traj, path)
    elif fmt == "kitti":
        write_kitti(traj, path)
    else:
        raise TrajectoryIOError(f"unknown trajectory format {fmt!r}; choose one of: {', '.join(FORMATS)}")
