"""gsslam: dense monocular and RGB-D SLAM on a GTSAM factor graph with a 3D Gaussian map.

Heavy modules (torch, gtsam, open3d) are imported where they are used, so ``import gsslam``
stays cheap. See ``docs/architecture.md`` for the data flow.
"""

import logging

from gsslam.errors import GsslamError

__version__ = "0.1.0"
__all__ = ["GsslamError", "__version__"]

logging.getLogger(__name__).addHandler(logging.NullHandler())
