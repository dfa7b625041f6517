"""Procedural ray-cast scenes with exact depth and poses: the one synthetic scene generator.

Everything synthetic in gsslam and its tests is rendered here (numpy, deterministic given a seed):

- ``scene.py``: surfaces (``Box`` room, ``Rectangle``, ``Sphere``, ``Cylinder``) and ``Scene.cast``
  -> image [H, W, 3] + exact z-depth [H, W] for a pose ``T_world_cam`` and ``CameraIntrinsics``.
- ``textures.py``: view-independent textures in surface coordinates (value noise, smooth noise,
  random blocks, constant) and their generators.
- ``presets.py``: named scenes, ``PRESETS = {room, block_room, planes, cylinder}``.
- ``trajectories.py``: camera paths (orbit, sway_line, outward_circle, wall_scan, forward_motion,
  pure_rotation) and the ``look_at`` / ``yaw_pose`` building blocks.
- ``dataset.py``: the registered ``synthetic`` dataset (``scene`` x ``trajectory`` by name, kwargs
  n_frames, width, height, seed, motion_scale, arc_deg, fps; or a YAML of them).
- ``submaps.py``: SING3R submaps cut from a scene with injected drift (loop tests, ``bench loop``).

Extending (e.g. long sequences): a new scene is a preset function returning a ``Scene`` (mix
surfaces; ``ConstantTexture`` walls give low texture) added to ``PRESETS``; a new path is a
function returning ``[N, 4, 4]`` poses (built from ``look_at`` / ``yaw_pose``; concatenate paths
to return after many frames; space poses far apart for fast rotations) added to
``dataset.TRAJECTORIES``. Per-frame photometric effects (exposure changes) belong in the
dataset's ``__getitem__``, applied to the rendered image, so the scene stays view-independent.
"""

from gsslam.datasets.synthetic.dataset import TRAJECTORIES, SyntheticDataset, SyntheticDatasetError
from gsslam.datasets.synthetic.presets import PRESETS, ROOM_HALF, block_room, cylinder, planes, room
from gsslam.datasets.synthetic.scene import Box, Cylinder, Rectangle, Scene, SceneError, Sphere
from gsslam.datasets.synthetic.submaps import SyntheticSubmaps, make_submaps

__all__ = [
    "PRESETS",
    "ROOM_HALF",
    "TRAJECTORIES",
    "Box",
    "Cylinder",
    "Rectangle",
    "Scene",
    "SceneError",
    "Sphere",
    "SyntheticDataset",
    "SyntheticDatasetError",
    "SyntheticSubmaps",
    "block_room",
    "cylinder",
    "make_submaps",
    "planes",
    "room",
]
