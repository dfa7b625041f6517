"""The dataset protocol and the registry of loaders by name.

A dataset is a lazily-read sequence of :class:`gsslam.types.Frame`: nothing is decoded until
``dataset[i]`` is asked for. Ground truth, when the dataset has it, is a
:class:`gsslam.types.Trajectory` of ``T_world_cam``; otherwise ``ground_truth()`` is ``None``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from gsslam.errors import GsslamError
from gsslam.types import CameraIntrinsics, Frame, ImuSamples, Trajectory


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


@runtime_checkable
class ImuDataset(Protocol):
    """A dataset that also gives IMU samples (``--imu``): EuRoC, TUM with ``imu="synthesized"``."""

    T_body_cam: Any  # [4, 4] numpy: the camera in the body frame (EuRoC cam0 T_BS)

    def imu(self) -> ImuSamples: ...


def iterate(dataset: Dataset, max_frames: int | None = None) -> Iterator[Frame]:
    n = len(dataset) if max_frames is None else min(len(dataset), max_frames)
    for i in range(n):
        yield dataset[i]


# Built-in loaders by name: "module:Class", imported only when that name is opened. One line per loader.
BUILTIN_LOADERS: dict[str, str] = {
    "tum": "gsslam.datasets.tum:TumRgbdDataset",
    "euroc": "gsslam.datasets.euroc:EurocDataset",
    "kitti": "gsslam.datasets.kitti:KittiOdometryDataset",
    "7scenes": "gsslam.datasets.sevenscenes:SevenScenesDataset",
    "images": "gsslam.datasets.images:ImageSequenceDataset",
    "rosbag": "gsslam.datasets.rosbag:RosbagDataset",
    "synthetic": "gsslam.datasets.synthetic.dataset:SyntheticDataset",
    "playback": "gsslam.datasets.playback:PlaybackDataset",
}

_REGISTRY: dict[str, Callable[..., Dataset]] = {}  # loaders registered at run time (user loaders)


def register_dataset(name: str) -> Callable[[type], type]:
    """Class decorator: make a (user) loader available to :func:`open_dataset` under ``name``.

    A registered loader takes precedence over a built-in one of the same name.
    """

    def deco(cls: type) -> type:
        _REGISTRY[name] = cls
        return cls

    return deco


def available_datasets() -> list[str]:
    return sorted(set(BUILTIN_LOADERS) | set(_REGISTRY))


def loader(name: str) -> Callable[..., Dataset]:
    """The loader class registered as ``name``; a built-in one is imported on first use."""
    if name in _REGISTRY:
        return _REGISTRY[name]
    if name not in BUILTIN_LOADERS:
        raise DatasetError(f"unknown dataset type '{name}'; choose one of: {', '.join(available_datasets())}")
    module, _, cls = BUILTIN_LOADERS[name].partition(":")
    return getattr(importlib.import_module(module), cls)


def open_dataset(name: str, path: str | Path, **kwargs: Any) -> Dataset:
    """Open the dataset at ``path`` with the loader registered as ``name``."""
    cls = loader(name)
    p = Path(path)
    if not p.exists():
        raise DatasetError(f"dataset path does not exist: {p}")
    return cls(p, **kwargs)
