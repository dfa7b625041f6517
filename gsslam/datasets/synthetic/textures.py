"""Procedural textures of the synthetic scenes, looked up in surface coordinates (metres).

A texture maps surface coordinates ``u``, ``v`` [N] (each surface defines its own, see
``scene.py``) to colours [N, 3] in [0, 1]. Colours depend on the surface point only, never on
the view, so reprojecting one frame into another through exact depth and poses reproduces them.

- ``ImageTexture``: a texel image stretched over ``extent`` (metres), bilinear lookup.
- ``BlockTexture``: one random value per ``cell`` x ``cell`` square, nearest lookup (hard corners:
  what ORB and the loop tests need).
- ``ConstantTexture``: one colour (a low-texture wall).

Generators (deterministic given the ``numpy.random.Generator``): ``value_noise`` (multi-scale
noise + checker + blobs, structure at every scale, for dense flow), ``smooth_noise`` (three
octaves of colour noise) and ``random_blocks``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class ImageTexture:
    image: np.ndarray  # [S_v, S_u, 3] float32 in [0, 1]
    extent: tuple[float, float]  # metres covered by the image along u and v

    def sample(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:  # u, v [N] -> [N, 3]
        hh, ww = self.image.shape[:2]
        return bilinear(self.image, u / self.extent[0] * (ww - 1), v / self.extent[1] * (hh - 1))


@dataclass(frozen=True)
class BlockTexture:
    values: np.ndarray  # [n, n] grey (or [n, n, 3]); values[i_u, i_v]
    cell: float  # metres per block

    def sample(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:  # u, v [N] -> [N, 3]
        n_u, n_v = self.values.shape[:2]
        iu = np.clip(np.floor(u / self.cell).astype(int), 0, n_u - 1)
        iv = np.clip(np.floor(v / self.cell).astype(int), 0, n_v - 1)
        out = self.values[iu, iv]
        return out if out.ndim == 2 else np.repeat(out[:, None], 3, axis=1)


@dataclass(frozen=True)
class ConstantTexture:
    colour: tuple[float, float, float] = (0.5, 0.5, 0.5)

    def sample(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:  # u, v [N] -> [N, 3]
        return np.broadcast_to(np.asarray(self.colour, np.float32), (len(u), 3))


def bilinear(tex: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:  # -> [N, 3]
    """Bilinear lookup of ``tex`` [H, W, 3] at texel coordinates ``u`` (column), ``v`` (row) [N], clamped."""
    hh, ww = tex.shape[:2]
    u = np.clip(u, 0, ww - 1.001)
    v = np.clip(v, 0, hh - 1.001)
    u0, v0 = u.astype(np.int64), v.astype(np.int64)
    fu, fv = (u - u0)[:, None], (v - v0)[:, None]
    top = tex[v0, u0] * (1 - fu) + tex[v0, u0 + 1] * fu
    bot = tex[v0 + 1, u0] * (1 - fu) + tex[v0 + 1, u0 + 1] * fu
    return (top * (1 - fv) + bot * fv).astype(np.float32)


def value_noise(rng: np.random.Generator, size: int) -> np.ndarray:  # -> [size, size, 3] in [0, 1]
    """Multi-scale value noise (octaves 4..96 cells), a checker and soft blobs, random colours."""
    acc = np.zeros((size, size), np.float32)
    amp_sum = 0.0
    for cells, amp in ((4, 1.0), (8, 0.8), (16, 0.7), (32, 0.6), (64, 0.5), (96, 0.4)):
        g = rng.random((cells, cells)).astype(np.float32)
        acc += amp * cv2.resize(g, (size, size), interpolation=cv2.INTER_CUBIC)
        amp_sum += amp
    acc /= amp_sum
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32)
    period = int(rng.integers(24, 64))
    checker = (((xx // period) + (yy // period)) % 2).astype(np.float32)
    checker = cv2.GaussianBlur(checker, (0, 0), 1.0)
    blobs = np.zeros((size, size), np.float32)
    for _ in range(12):
        cx, cy = rng.random(2) * size
        r = rng.uniform(0.02, 0.08) * size
        blobs += np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * r * r)).astype(np.float32)
    base = np.stack([acc, 0.6 * acc + 0.4 * checker, 0.5 * acc + 0.5 * np.clip(blobs, 0, 1)], -1)
    mix = rng.uniform(0.3, 1.0, size=(3, 3)).astype(np.float32)
    mix /= mix.sum(1, keepdims=True)
    tex = base @ mix.T
    lo, hi = np.percentile(tex, 1), np.percentile(tex, 99)
    return np.clip(0.1 + 0.8 * (tex - lo) / max(hi - lo, 1e-6), 0.0, 1.0).astype(np.float32)


def smooth_noise(rng: np.random.Generator, size: int = 512) -> np.ndarray:  # -> [size, size, 3] in [0, 1]
    """Three octaves (8, 32, 128 cells) of band-limited colour noise."""
    t = np.zeros((size, size, 3), np.float32)
    for octave, amp in ((8, 0.5), (32, 0.3), (128, 0.2)):
        small = rng.random((octave, octave, 3)).astype(np.float32)
        t += amp * cv2.resize(small, (size, size), interpolation=cv2.INTER_CUBIC)
    return np.clip(t, 0, 1)


def random_blocks(rng: np.random.Generator, n: int, lo: float = 0.05, hi: float = 0.95) -> np.ndarray:
    """[n, n] grey values uniform in [lo, hi] (one per block)."""
    return rng.uniform(lo, hi, size=(n, n))
