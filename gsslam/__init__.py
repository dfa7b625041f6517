"""gsslam: dense monocular and RGB-D SLAM on a GTSAM factor graph with a 3D Gaussian map.

The public facade (docs/python.md)::

    import gsslam
    slam = gsslam.Slam((fx, fy, cx, cy, width, height), mode="rgbd")
    T_world_cam = slam.register_frame(image, timestamp, depth=depth)
    slam.finish(); slam.save("out/")

    result = gsslam.run("path/to/tum_sequence", dataset="tum", out="out/", mode="rgbd")

Heavy modules (torch, gtsam, open3d) are imported where they are used, so ``import gsslam``
stays cheap: :class:`Slam` and :class:`Plugin` are loaded on first access. See
``docs/architecture.md`` for the data flow.
"""

import importlib
import logging

from gsslam.errors import GsslamError

__version__ = "0.1.0"
__all__ = ["GsslamError", "Plugin", "Slam", "load_config", "run", "__version__"]

_LAZY = {
    "Slam": "gsslam.session",
    "Plugin": "gsslam.slam.plugins",
    "GraphEvent": "gsslam.slam.plugins",
    "CameraIntrinsics": "gsslam.types",
    "load_config": "gsslam.config",
}


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    if name == "run":  # the package gsslam.run is callable: gsslam.run(path, ...)
        return importlib.import_module("gsslam.run")
    raise AttributeError(f"module 'gsslam' has no attribute {name!r}")


logging.getLogger(__name__).addHandler(logging.NullHandler())
