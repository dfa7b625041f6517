"""A real sequence played forward and then backward: a revisit with ground truth, for loop closure.

``RevisitDataset(base, n)`` hands out frames ``0..n-1`` of ``base`` and then ``n-2..0`` again
(``2 n - 1`` frames). The backward half sees the same views as the forward half, so submaps built on
it overlap the first ones and loop closure has something to find. Timestamps are mirrored
(``t' = 2 t_last - t``) so they keep increasing; the ground truth is mirrored the same way (the pose
at a mirrored time is the pose at the original time), so ATE compares directly with and without loops.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from gsslam.datasets.base import Dataset, DatasetError
from gsslam.types import Frame, Trajectory


class RevisitDataset:
    """``base`` frames ``0..n-1`` then ``n-2..0``; see the module docstring."""

    def __init__(self, base: Dataset, n: int | None = None) -> None:
        n = len(base) if n is None else min(int(n), len(base))
        if n < 2:
            raise DatasetError(f"a revisit needs at least 2 frames of the base sequence, got {n}")
        self.base = base
        self.n = n
        self.name = f"{getattr(base, 'name', type(base).__name__)}_revisit{n}"
        self.intrinsics = base.intrinsics
        self.has_depth = base.has_depth
        ts = np.asarray(base.timestamps()[:n], dtype=np.float64)
        self._src = np.concatenate([np.arange(n), np.arange(n - 2, -1, -1)])
        self._t_last = float(ts[-1])
        self._ts = np.concatenate([ts, 2 * self._t_last - ts[n - 2 :: -1]])

    def __len__(self) -> int:
        return len(self._src)

    def source_index(self, index: int) -> int:
        """Index in the base sequence of frame ``index``."""
        return int(self._src[index])

    def __getitem__(self, index: int) -> Frame:
        if not 0 <= index < len(self):
            raise IndexError(f"revisit frame {index} out of range [0, {len(self)})")
        f = self.base[self.source_index(index)]
        return dataclasses.replace(f, index=index, timestamp=float(self._ts[index]))

    def timestamps(self) -> list[float]:
        return [float(t) for t in self._ts]

    def ground_truth(self) -> Trajectory | None:
        gt = self.base.ground_truth()
        if gt is None:
            return None
        t0 = float(self._ts[0])
        fwd = (gt.timestamps >= t0 - 0.1) & (gt.timestamps <= self._t_last)
        back = fwd & (gt.timestamps < self._t_last)
        t_back = 2 * self._t_last - gt.timestamps[back]
        ts = np.concatenate([gt.timestamps[fwd], t_back[::-1]])
        poses = np.concatenate([gt.poses[fwd], gt.poses[back][::-1]])
        return Trajectory(ts, poses)
