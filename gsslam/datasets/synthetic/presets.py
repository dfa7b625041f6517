"""Named scenes, each deterministic given ``seed`` (``PRESETS`` maps names to builders).

- ``room``: a 6 x 3 x 6 m box of value-noise walls (one brightness per wall) with three textured
  spheres standing on the floor near the centre: the ``synthetic`` dataset's scene.
- ``block_room``: a box of random grey blocks (``cell`` metres): corners for ORB, no repetition;
  the loop-closure scenes.
- ``planes``: a back wall, a floor, a left wall and a small tilted panel (colour noise); the
  frontend encoder tests; nothing behind the camera (depth NaN there).
- ``cylinder``: the inside of a vertical cylinder, plain unless a texture is given; the graph
  tests' submap chains (only the point maps matter there).
- ``furnished_room``: a 4.8 x 2.6 x 4.8 m office-sized box (value-noise walls) with three spheres on
  the floor near the centre and panels against the walls (a table top, a tilted board, two cabinet
  fronts): depth edges and parallax everywhere, far corners beyond a Kinect v1's 4 m; the
  ``room_walk`` path's scene.

A new preset is a function returning a ``Scene``, added to ``PRESETS``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from gsslam.datasets.synthetic.scene import Box, Cylinder, Rectangle, Scene, Sphere
from gsslam.datasets.synthetic.textures import (
    BlockTexture,
    ConstantTexture,
    ImageTexture,
    random_blocks,
    smooth_noise,
    value_noise,
)

ROOM_HALF = np.array([3.0, 1.5, 3.0])  # the ``room`` preset's half extents (x, y, z), metres
TEXTURE_SIZE = 384  # texels per wall side in ``room``


def room(seed: int = 0, half_extent=ROOM_HALF, n_spheres: int = 3) -> Scene:
    rng = np.random.default_rng(seed)
    he = np.asarray(half_extent, np.float64)
    images = [value_noise(rng, TEXTURE_SIZE) for _ in range(6)]
    textures = []
    for f, img in enumerate(images):
        a, b = [ax for ax in range(3) if ax != f // 2]
        textures.append(ImageTexture(img, (2 * he[a], 2 * he[b])))
    brightness = rng.uniform(0.75, 1.0, size=6).astype(np.float32)
    box = Box(he, textures, brightness)
    spheres = []
    for ang in rng.uniform(0, 2 * np.pi, size=n_spheres) + np.arange(n_spheres) * 2.1:
        r = float(rng.uniform(0.25, 0.45))
        d = float(rng.uniform(0.2, 0.6))
        c = np.array([d * np.cos(ang), he[1] - r - float(rng.uniform(0.0, 0.8)), d * np.sin(ang)])
        spheres.append((c, r))
    surfaces = [box] + [
        Sphere(c, r, ImageTexture(value_noise(rng, TEXTURE_SIZE // 2), (1.0, 1.0))) for c, r in spheres
    ]
    return Scene(surfaces, room=box)


def block_room(half_extent=(4.0, 1.5, 4.0), cell: float = 0.2, seed: int = 0) -> Scene:
    rng = np.random.default_rng(seed)
    he = np.asarray(half_extent, dtype=np.float64)
    n = int(np.ceil(2 * he.max() / cell)) + 2
    walls = [BlockTexture(random_blocks(rng, n), cell) for _ in range(6)]  # +x +y +z -x -y -z
    box = Box(he, [walls[3], walls[0], walls[4], walls[1], walls[5], walls[2]])
    return Scene([box], room=box)


def planes(seed: int = 0) -> Scene:
    rng = np.random.default_rng(seed)
    ex, ey, ez = np.eye(3)
    tilted = np.array([1.0, 0, 0.3]) / np.hypot(1, 0.3)
    layout = [  # (corner, axis u, axis v, extent u, extent v)
        (np.array([-2.0, -1.5, 4.0]), ex, ey, 4.0, 3.0),  # back wall
        (np.array([-2.0, 1.0, 0.5]), ex, ez, 4.0, 3.5),  # floor (y down)
        (np.array([-1.6, -1.5, 0.5]), ez, ey, 3.5, 2.5),  # left wall
        (np.array([0.1, -0.2, 2.5]), tilted, ey, 0.7, 0.7),  # a floating panel
    ]
    textures = [smooth_noise(rng) for _ in layout]
    return Scene(
        [
            Rectangle(p, u, v, (eu, ev), ImageTexture(t, (eu, ev)))
            for (p, u, v, eu, ev), t in zip(layout, textures)
        ]
    )


FURNISHED_HALF = np.array([2.4, 1.3, 2.4])  # ``furnished_room``'s half extents (x, y, z), metres


def furnished_room(seed: int = 0) -> Scene:
    rng = np.random.default_rng(seed)
    he = FURNISHED_HALF
    textures = []
    for f in range(6):
        a, b = [ax for ax in range(3) if ax != f // 2]
        textures.append(ImageTexture(value_noise(rng, TEXTURE_SIZE), (2 * he[a], 2 * he[b])))
    box = Box(he, textures, rng.uniform(0.75, 1.0, size=6).astype(np.float32))
    surfaces: list = [box]
    for k in range(3):  # on the floor (y = he[1]), within 0.45 m of the centre: below the camera's path
        ang = 2.1 * k + float(rng.uniform(0.0, 0.6))
        r = float(rng.uniform(0.18, 0.26))
        d = float(rng.uniform(0.15, 0.3))
        c = np.array([d * np.cos(ang), he[1] - r, d * np.sin(ang)])
        surfaces.append(Sphere(c, r, ImageTexture(value_noise(rng, TEXTURE_SIZE // 2), (1.0, 1.0))))
    ex, ey, ez = np.eye(3)
    lean = np.array([0.0, -0.9, -0.44]) / np.hypot(0.9, 0.44)
    layout = [  # (corner, axis u, axis v, extent u, extent v): 0.3-0.6 m in front of a wall
        (np.array([-0.8, 0.55, 1.6]), ex, ez, 1.4, 0.6),  # a table top 0.75 m above the floor
        (np.array([1.9, -0.6, -1.2]), ez, ey, 1.0, 1.9),  # a cabinet front facing -x
        (np.array([-1.8, -0.9, 0.2]), -ez, ey, 0.9, 2.2),  # a cabinet front facing +x
        (np.array([-0.5, 1.3, -1.6]), ex, lean, 1.2, 1.2),  # a board on the floor leaning towards -z
    ]
    for corner, u, v, eu, ev in layout:
        surfaces.append(Rectangle(corner, u, v, (eu, ev), ImageTexture(smooth_noise(rng), (eu, ev))))
    return Scene(surfaces, room=box)


def cylinder(radius: float = 10.0, texture=None) -> Scene:
    return Scene([Cylinder(radius, texture or ConstantTexture())])


PRESETS: dict[str, Callable[..., Scene]] = {
    "room": room,
    "block_room": block_room,
    "planes": planes,
    "cylinder": cylinder,
    "furnished_room": furnished_room,
}
