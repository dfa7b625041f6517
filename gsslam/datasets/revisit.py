"""A real sequence played forward and then backward: a revisit with ground truth, for loop closure.

``RevisitDataset(base, n)`` hands out frames ``0..n-1`` of ``base`` and then ``n-2..0`` again
(``2 n - 1`` frames): :class:`gsslam.datasets.playback.Playback` with ``pattern="fb"``. The backward
half sees the same views as the forward half, so submaps built on it overlap the first ones and loop
closure has something to find. Timestamps keep increasing by the base's frame period; the ground
truth of a played frame is the base's at the source frame's time, so ATE compares directly with and
without loops.
"""

from __future__ import annotations

from gsslam.datasets.base import Dataset
from gsslam.datasets.playback import Playback


class RevisitDataset(Playback):
    """``base`` frames ``0..n-1`` then ``n-2..0``; see the module docstring."""

    def __init__(self, base: Dataset, n: int | None = None) -> None:
        super().__init__(base, pattern="fb", n=n)
        self.name = f"{getattr(base, 'name', type(base).__name__)}_revisit{self.n}"
