"""Long sequences from short real ones: a base sequence replayed by a pattern, with pauses and jumps.

``open_dataset("playback", path, base="tum", pattern="fbf", pause_every=0, pause_len=0, jump_every=0,
jump_len=0, misregister=None, seed=0, n=None, stride=1, degrade=None, **base_kwargs)`` opens
``open_dataset(base, path, **base_kwargs)`` (its first ``n`` frames when ``n`` is given) and plays it
by a plan of source frames:

- ``pattern``: letters ``f`` (forward ``0..n-1``) and ``b`` (backward ``n-1..0``), concatenated; a
  segment that starts on the frame the previous one ended on skips it (``"fb"`` is ``0..n-1, n-2..0``;
  ``"fbf"`` continues ``1..n-1``), so the camera turns around without a duplicated frame.
- ``stride``: every ``stride``-th source frame only (``0, s, 2s, ..``, backward the same frames): the
  camera played ``stride`` times faster, with ``stride`` times the motion per frame (a quicker hand).
- jumps: every ``jump_every`` played frames, the next ``jump_len`` frames of the plan are dropped (a
  fast motion / frame drop); pauses: every ``pause_every`` played frames, the last frame is repeated
  ``pause_len`` more times (a camera at rest). Jumps are applied first. The phase of both is 0 for
  ``seed=0`` and drawn from ``seed`` otherwise.
- timestamps: ``t0 + k * dt``, strictly increasing, with ``t0`` the base's first timestamp and ``dt``
  the base's median frame period.
- ground truth: one pose per played frame, the base ground truth *interpolated* at the source frame's
  timestamp (linear translation, geodesic rotation between the two nearest ground-truth rows, which
  must lie within ``gt_max_gap`` seconds; TUM's is 100 Hz motion capture); frames outside it get none.
- ``degrade``: ``None`` or a dict ``{"shutter", "blur_samples", "exposure_amp", "exposure_period",
  "seed"}`` (see :mod:`gsslam.datasets.degraded`): motion blur along the ground-truth motion of the
  played frames (needs depth and ground truth) and auto-exposure swings, applied to the colour image.
- ``misregister``: ``None`` or a dict ``{"baseline_m", "focal_scale", "report", "rotation_deg",
  "offset_m", "ground_truth"}`` (see :mod:`gsslam.datasets.misregistered`): the depth is replaced by what an
  unregistered Kinect v1 depth camera would see, handed out at the colour pixels.

:class:`Playback` wraps an already opened dataset the same way (``Playback(base, pattern="fb")``
is the forward-then-backward revisit of :mod:`gsslam.datasets.revisit`).
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Any

import numpy as np

from gsslam.datasets.base import Dataset, DatasetError, open_dataset
from gsslam.datasets.degraded import Degradation, apply_exposure, exposure_ends, motion_blur
from gsslam.datasets.misregistered import Misregistration, misregister_depth
from gsslam.geometry import so3_exp, so3_log
from gsslam.types import Frame, Trajectory

log = logging.getLogger(__name__)


class PlaybackError(DatasetError):
    """A playback plan cannot be built (bad pattern, too few frames)."""


def playback_plan(
    n: int,
    pattern: str = "fbf",
    pause_every: int = 0,
    pause_len: int = 0,
    jump_every: int = 0,
    jump_len: int = 0,
    seed: int = 0,
    stride: int = 1,
) -> np.ndarray:  # -> [M] int64 source indices
    """Source frame of every played frame (module docstring)."""
    if n < 2:
        raise PlaybackError(f"playback needs at least 2 frames of the base sequence, got {n}")
    if not pattern or set(pattern) - {"f", "b"}:
        raise PlaybackError(f"pattern must be a non-empty string of 'f' and 'b', got {pattern!r}")
    for name, val in (("pause_every", pause_every), ("pause_len", pause_len), ("jump_every", jump_every), ("jump_len", jump_len)):
        if int(val) < 0:
            raise PlaybackError(f"{name} must be >= 0, got {val}")
    if int(stride) < 1 or (n - 1) // int(stride) < 1:
        raise PlaybackError(f"stride must be >= 1 and leave at least 2 of the {n} frames, got {stride}")
    fwd = list(range(0, n, int(stride)))
    plan: list[int] = []
    for c in pattern:
        seg = fwd if c == "f" else fwd[::-1]
        if plan and seg[0] == plan[-1]:
            seg = seg[1:]
        plan.extend(seg)
    rng = np.random.default_rng(seed)
    if jump_every > 0 and jump_len > 0:
        phase = 0 if seed == 0 else int(rng.integers(jump_every))
        kept: list[int] = []
        k = 0
        while k < len(plan):
            kept.append(plan[k])
            k += 1
            if (len(kept) + phase) % jump_every == 0:
                k += jump_len
        plan = kept
    if pause_every > 0 and pause_len > 0:
        phase = 0 if seed == 0 else int(rng.integers(pause_every))
        paused: list[int] = []
        for k, s in enumerate(plan):
            paused.append(s)
            if (k + 1 + phase) % pause_every == 0:
                paused.extend([s] * pause_len)
        plan = paused
    return np.asarray(plan, dtype=np.int64)


def interpolate_trajectory(
    traj: Trajectory, times: np.ndarray, max_gap: float
) -> tuple[np.ndarray, np.ndarray]:  # -> ok [M] bool, poses [M, 4, 4]
    """Poses of ``traj`` at ``times`` [M]: linear translation and geodesic rotation between the two
    bracketing rows, valid only where both exist and lie within ``max_gap`` seconds of each other."""
    ts = traj.timestamps
    times = np.asarray(times, dtype=np.float64)
    poses = np.tile(np.eye(4), (len(times), 1, 1))
    ok = np.zeros(len(times), dtype=bool)
    hi = np.searchsorted(ts, times)
    for k, (t, j) in enumerate(zip(times, hi)):
        if j < len(ts) and ts[j] == t:
            poses[k] = traj.poses[j]
            ok[k] = True
            continue
        if j == 0 or j == len(ts) or ts[j] - ts[j - 1] > max_gap:
            continue
        a, b = traj.poses[j - 1], traj.poses[j]
        u = (t - ts[j - 1]) / (ts[j] - ts[j - 1])
        poses[k, :3, :3] = a[:3, :3] @ so3_exp(u * so3_log(a[:3, :3].T @ b[:3, :3]))
        poses[k, :3, 3] = (1.0 - u) * a[:3, 3] + u * b[:3, 3]
        ok[k] = True
    return ok, poses


class Playback:
    """``base`` replayed by a plan (module docstring); follows the dataset protocol."""

    def __init__(
        self,
        base: Dataset,
        pattern: str = "fbf",
        pause_every: int = 0,
        pause_len: int = 0,
        jump_every: int = 0,
        jump_len: int = 0,
        misregister: dict[str, Any] | Misregistration | None = None,
        seed: int = 0,
        n: int | None = None,
        gt_max_gap: float = 0.1,
        stride: int = 1,
        degrade: dict[str, Any] | Degradation | None = None,
    ) -> None:
        n = len(base) if n is None else min(int(n), len(base))
        self.base = base
        self.n = n
        self._src = playback_plan(n, pattern, pause_every, pause_len, jump_every, jump_len, seed, stride)
        self.degradation = (
            degrade if isinstance(degrade, Degradation) or degrade is None else Degradation.from_dict(degrade)
        )
        if self.degradation is not None and self.degradation.blurs and not base.has_depth:
            raise PlaybackError("degrade.shutter > 0 (motion blur) needs a base sequence with depth")
        self.misregistration = (
            misregister if isinstance(misregister, Misregistration) or misregister is None
            else Misregistration.from_dict(misregister)
        )
        if self.misregistration is not None and not base.has_depth:
            raise PlaybackError("misregister needs a base sequence with depth")
        if self.misregistration is not None and self.misregistration.raycast:
            raise PlaybackError("misregister.raycast needs a synthetic scene; playbacks re-project depth")
        self._colour_intrinsics = base.intrinsics
        self.intrinsics = (
            base.intrinsics if self.misregistration is None
            else self.misregistration.reported_intrinsics(base.intrinsics)
        )
        self.has_depth = base.has_depth
        self.intrinsics_nominal = getattr(base, "intrinsics_nominal", False) or (
            self.misregistration is not None and self.misregistration.report == "depth"
        )  # the depth camera's intrinsics handed out for colour, as 7-Scenes does
        self.name = f"{getattr(base, 'name', type(base).__name__)}_{pattern}{n}" + (
            f"_s{stride}" if stride != 1 else ""
        )
        base_ts = np.asarray(base.timestamps()[:n], dtype=np.float64)
        self._src_ts = base_ts[self._src]
        dt = float(np.median(np.diff(base_ts))) if n > 1 else 1.0
        if not dt > 0:
            raise PlaybackError(f"base timestamps do not increase (median step {dt})")
        self._ts = base_ts[0] + dt * np.arange(len(self._src))
        self._gt_ok = np.zeros(len(self._src), dtype=bool)
        self._gt_poses: np.ndarray | None = None
        gt = base.ground_truth()
        if gt is not None and len(gt):
            self._gt_ok, self._gt_poses = interpolate_trajectory(gt, self._src_ts, gt_max_gap)
        if self.degradation is not None and self.degradation.blurs and not self._gt_ok.any():
            raise PlaybackError("degrade.shutter > 0 (motion blur) needs ground truth for the motion")
        log.info(
            "playback %s: %d frames from %d (%s), gt on %d, misregister=%s, degrade=%s",
            self.name, len(self), n, pattern, int(self._gt_ok.sum()), self.misregistration, self.degradation,
        )

    def __len__(self) -> int:
        return len(self._src)

    def source_index(self, index: int) -> int:
        """Index in the base sequence of played frame ``index``."""
        return int(self._src[index])

    def timestamps(self) -> list[float]:
        return [float(t) for t in self._ts]

    def __getitem__(self, index: int) -> Frame:
        if not -len(self) <= index < len(self):
            raise IndexError(f"playback frame {index} out of range [0, {len(self)})")
        index = int(index) % len(self)
        f = self.base[self.source_index(index)]
        image = self._degraded_image(index, f.image, f.depth)
        depth = f.depth
        mr = self.misregistration
        if mr is not None and depth is not None:
            depth = misregister_depth(
                depth, self._colour_intrinsics, mr.baseline_m, mr.focal_scale, mr.rotation_deg, mr.offset_m
            )
        gt = self._truth(self._gt_poses[index]) if self._gt_ok[index] else None
        return dataclasses.replace(
            f, index=index, timestamp=float(self._ts[index]), image=image, intrinsics=self.intrinsics,
            depth=depth, T_world_cam_gt=gt,
        )

    def _gt_pose(self, index: int) -> np.ndarray | None:
        if not 0 <= index < len(self) or not self._gt_ok[index]:
            return None
        return self._gt_poses[index]

    def _degraded_image(self, index: int, image: np.ndarray, depth: np.ndarray | None) -> np.ndarray:
        """The colour image of played frame ``index`` as the degradation makes it (the base's otherwise)."""
        deg = self.degradation
        if deg is None:
            return image
        T_k = self._gt_pose(index)
        if deg.blurs and T_k is not None and depth is not None:
            ends = exposure_ends(deg, self._gt_pose(index - 1), T_k, self._gt_pose(index + 1))
            image = motion_blur(image, depth, self._colour_intrinsics, ends, deg.blur_samples)
        return apply_exposure(image, deg.gain(index))

    @property
    def ground_truth_camera(self) -> str:  # the camera ground_truth() poses (misregister.ground_truth)
        return "colour" if self.misregistration is None else self.misregistration.ground_truth

    def _truth(self, poses: np.ndarray) -> np.ndarray:  # colour camera poses as the ground truth gives them
        mr = self.misregistration
        return poses.copy() if mr is None else mr.ground_truth_poses(poses)

    def ground_truth(self) -> Trajectory | None:
        if not self._gt_ok.any():
            return None
        poses = self._truth(self._gt_poses[self._gt_ok])
        return Trajectory(self._ts[self._gt_ok], poses, meta={"playback": self.name})


class PlaybackDataset(Playback):
    """The registered loader: opens ``base`` at ``path`` and plays it (module docstring)."""

    def __init__(
        self,
        path: str | Path,
        *,
        base: str = "tum",
        pattern: str = "fbf",
        pause_every: int = 0,
        pause_len: int = 0,
        jump_every: int = 0,
        jump_len: int = 0,
        misregister: dict[str, Any] | None = None,
        seed: int = 0,
        n: int | None = None,
        gt_max_gap: float = 0.1,
        stride: int = 1,
        degrade: dict[str, Any] | None = None,
        **base_kwargs: Any,
    ) -> None:
        if base == "playback":
            raise PlaybackError("base cannot be 'playback' itself")
        super().__init__(
            open_dataset(base, path, **base_kwargs), pattern, pause_every, pause_len, jump_every,
            jump_len, misregister, seed, n, gt_max_gap, stride=stride, degrade=degrade,
        )
