"""A contiguous range of another dataset's frames: ``FrameRange(ds, start, stop)`` is ``ds[start:stop]``.

It keeps the dataset protocol (lazy frames, intrinsics, ground truth) so that a run, a batch entry or a
user script can start part-way into a sequence. Ground truth stays the whole sequence's: evaluation
associates poses by timestamp, so the frames of the range find theirs.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from gsslam.datasets.base import DatasetError
from gsslam.types import Frame, Trajectory


class FrameRange:
    """Frames ``[start, stop)`` of ``dataset`` (``stop=None``: to the end), indexed from 0.

    A frame keeps its timestamp; its ``index`` is its place in the range.
    """

    def __init__(self, dataset: Any, start: int = 0, stop: int | None = None) -> None:
        n = len(dataset)
        if isinstance(start, bool) or not isinstance(start, int) or not 0 <= start < n:
            raise DatasetError(f"start frame {start!r} is outside the sequence's {n} frames (0..{n - 1})")
        stop = n if stop is None else stop
        if isinstance(stop, bool) or not isinstance(stop, int) or not start < stop <= n:
            raise DatasetError(f"frame range [{start}, {stop}) is empty or beyond the sequence's {n} frames")
        self.dataset = dataset
        self.start, self.stop = start, stop
        self.name = f"{getattr(dataset, 'name', 'dataset')}[{start}:{stop}]"
        self.intrinsics = dataset.intrinsics
        self.has_depth = getattr(dataset, "has_depth", False)

    def __len__(self) -> int:
        return self.stop - self.start

    def __getitem__(self, index: int) -> Frame:
        if not -len(self) <= index < len(self):
            raise IndexError(f"frame {index} is outside the range's {len(self)} frames")
        frame = self.dataset[self.start + index % len(self)]
        # the run keys everything by frame index and reads frames back by it (keyframe images, renders)
        return dataclasses.replace(frame, index=index % len(self))

    def timestamps(self) -> list[float]:
        return list(self.dataset.timestamps())[self.start : self.stop]

    def ground_truth(self) -> Trajectory | None:
        return self.dataset.ground_truth()

    def __getattr__(self, name: str) -> Any:
        # loader-specific extras (IMU samples, calibration files, ...) are the underlying dataset's
        if name == "dataset":
            raise AttributeError(name)
        return getattr(self.dataset, name)
