"""Dataset loaders, registered by name: tum, euroc, kitti, 7scenes, images, synthetic."""

from gsslam.datasets.base import (
    Dataset,
    DatasetError,
    available_datasets,
    iterate,
    open_dataset,
    register_dataset,
)

__all__ = ["Dataset", "DatasetError", "available_datasets", "iterate", "open_dataset", "register_dataset"]
