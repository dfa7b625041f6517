"""The dataset protocol and the registry of loaders by name.

A dataset is a lazily-read sequence of :class:`gsslam.types.Frame`: nothing is decoded until
``dataset[i]`` is asked for. Ground truth, when the dataset has it, is a
:class:`gsslam.types.Trajectory` of ``T_world_cam``; otherwise ``ground_truth()`` is ``None``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from gsslam.errors import GsslamError
from gsslam.types import CameraIntrinsics, Frame, Trajectory


class DatasetError(GsslamError):
    """A dataset folder or file is missing, malformed or inconsistent."""


@runtime_checkable
class Dataset(Protocol):
    name: str
    intrinsics: CameraIntrinsics  # of the frames handed out (already undistorted)
    has_depth: bool

    def __len__(self) -> int: ...

    def __getitem__(self, index: int) -> Frame: ...

    def timestamps(self) -> list[float]: ...

    def ground_truth(self) -> Trajectory | None: ...


def iterate(dataset: Dataset, max_frames: int | None = None) -> Iterator[Frame]:
    n = len(dataset) if max_frames is None else min(len(dataset), max_frames)
    for i in range(n):
        yield dataset[i]


_REGISTRY: dict[str, Callable[..., Dataset]] = {}


def register_dataset(name: str) -> Callable[[type], type]:
    """Class decorator: make a loader available to :func:`open_dataset` under ``name``."""

    def deco(cls: type) -> type:
        _REGISTRY[name] = cls
        return cls

    return deco


def available_datasets() -> list[str]:
    _load_builtin()
    return sorted(_REGISTRY)


def open_dataset(name: str, path: str | Path, **kwargs: Any) -> Dataset:
    """Open the dataset at ``path`` with the loader registered as ``name``."""
    _load_builtin()
    if name not in _REGISTRY:
        raise DatasetError(f"unknown dataset type '{name}'; choose one of: {', '.join(sorted(_REGISTRY))}")
    p = Path(path)
    if not p.exists():
        raise DatasetError(f"dataset path does not exist: {p}")
    return _REGISTRY[name](p, **kwargs)


def _load_builtin() -> None:
    # Importing the modules runs their @register_dataset decorators.
    from gsslam.datasets import euroc, images, kitti, sevenscenes, synthetic, tum  # noqa: F401
    from gsslam.datasets import playback  # noqa: F401
