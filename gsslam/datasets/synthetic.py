"""A procedural RGB-D scene with exact depth and poses, rendered lazily by ray casting in numpy.

The scene is a textured room (an axis-aligned box, 6 x 3 x 6 m, centred on the world origin,
y pointing down) with a few textured spheres standing in it. Textures are multi-scale value
noise plus a checker and blobs, so dense optical flow has structure at every scale. Colours are
view-independent functions of the surface point, so reprojecting one frame into another through
the exact depth and poses reproduces the colours (up to bilinear texture sampling).

Trajectories (``T_world_cam``, OpenCV camera axes):

- ``"orbit"``: an arc of ``arc_deg`` degrees on a circle around the room centre, looking at it.
- ``"line"``: forward motion along +z with a gentle sideways sway, looking forward.
- ``"loop"``: a full circle looking at the centre; the last frame comes back to the first pose,
  so the sequence revisits its start (loop closure).

``motion_scale`` scales the path (radius / length) inside the room. Everything is deterministic
given ``seed``.

``open_dataset("synthetic", path)``: ``path`` is a YAML file (or a folder holding
``synthetic.yaml``) whose keys are the constructor's keyword arguments, e.g.::

    n_frames: 60
    width: 320
    height: 240
    trajectory: loop
    seed: 3
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from gsslam.datasets.base import DatasetError
from gsslam.geometry import make_T, pixel_grid
from gsslam.types import CameraIntrinsics, Frame, Trajectory

ROOM_HALF = np.array([3.0, 1.5, 3.0])  # half extents of the room box (x, y, z), metres
TEXTURE_SIZE = 384  # texels per face side
TRAJECTORIES = ("orbit", "line", "loop")
_PARAMS = ("n_frames", "width", "height", "trajectory", "seed", "motion_scale", "arc_deg", "fps")


class SyntheticDatasetError(DatasetError):
    """Bad parameters for the synthetic scene."""


def _noise_texture(rng: np.random.Generator, size: int) -> np.ndarray:  # -> [size, size, 3] in [0, 1]
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


def _look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:  # -> T_world_cam [4, 4]
    """OpenCV camera at ``eye`` looking at ``target``, world y (down) as the camera's down."""
    z = target - eye
    z = z / np.linalg.norm(z)
    x = np.cross(np.array([0.0, 1.0, 0.0]), z)
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    return make_T(np.stack([x, y, z], axis=1), eye)


class SyntheticDataset:
    """Lazily ray-cast RGB-D frames of a textured room; exact depth and ground-truth poses."""

    name = "synthetic"
    has_depth = True

    def __init__(
        self,
        path: str | Path | None = None,
        n_frames: int = 60,
        width: int = 320,
        height: int = 240,
        trajectory: str = "orbit",
        seed: int = 0,
        motion_scale: float = 1.0,
        arc_deg: float = 90.0,
        fps: float = 30.0,
    ) -> None:
        params: dict[str, Any] = dict(
            n_frames=n_frames,
            width=width,
            height=height,
            trajectory=trajectory,
            seed=seed,
            motion_scale=motion_scale,
            arc_deg=arc_deg,
            fps=fps,
        )
        if path is not None:
            params.update(self._read_params(Path(path)))
        self.params = params
        self.n_frames = int(params["n_frames"])
        self.trajectory = str(params["trajectory"])
        self.motion_scale = float(params["motion_scale"])
        self.fps = float(params["fps"])
        w, h = int(params["width"]), int(params["height"])
        if self.n_frames < 1:
            raise SyntheticDatasetError(f"n_frames must be >= 1, got {self.n_frames}")
        if w < 16 or h < 16:
            raise SyntheticDatasetError(f"image size must be at least 16x16, got {w}x{h}")
        if self.trajectory not in TRAJECTORIES:
            raise SyntheticDatasetError(
                f"trajectory must be one of {', '.join(TRAJECTORIES)}, got {self.trajectory!r}"
            )
        if not 0.0 < self.motion_scale <= 2.0:
            raise SyntheticDatasetError(f"motion_scale must be in (0, 2], got {self.motion_scale}")
        f = 0.8 * w
        self.intrinsics = CameraIntrinsics(f, f, (w - 1) / 2.0, (h - 1) / 2.0, w, h)
        rng = np.random.default_rng(int(params["seed"]))
        self._textures = [_noise_texture(rng, TEXTURE_SIZE) for _ in range(6)]
        self._face_shade = rng.uniform(0.75, 1.0, size=6).astype(np.float32)
        self._spheres = self._make_spheres(rng)
        self._sphere_textures = [_noise_texture(rng, TEXTURE_SIZE // 2) for _ in self._spheres]
        self._poses = self._make_poses(float(params["arc_deg"]))
        K_inv = np.linalg.inv(self.intrinsics.K)
        uv1 = np.concatenate([pixel_grid(w, h).reshape(-1, 2), np.ones((w * h, 1))], axis=1)
        self._rays_cam = uv1 @ K_inv.T  # [H*W, 3], z = 1

    @staticmethod
    def _read_params(path: Path) -> dict:
        p = path / "synthetic.yaml" if path.is_dir() else path
        if not p.is_file():
            raise SyntheticDatasetError(
                f"no synthetic scene description at {p} (a YAML of {', '.join(_PARAMS)})"
            )
        try:
            data = yaml.safe_load(p.read_text()) or {}
        except yaml.YAMLError as e:
            raise SyntheticDatasetError(f"{p} is not valid YAML: {e}") from None
        if not isinstance(data, dict):
            raise SyntheticDatasetError(f"{p} must hold a mapping of parameters")
        unknown = set(data) - set(_PARAMS)
        if unknown:
            raise SyntheticDatasetError(f"{p}: unknown keys {sorted(unknown)}; known: {', '.join(_PARAMS)}")
        return data

    def _make_spheres(self, rng: np.random.Generator) -> list[tuple[np.ndarray, float]]:
        spheres = []
        for ang in rng.uniform(0, 2 * np.pi, size=3) + np.array([0.0, 2.1, 4.2]):
            r = float(rng.uniform(0.25, 0.45))
            d = float(rng.uniform(0.2, 0.6))
            c = np.array([d * np.cos(ang), ROOM_HALF[1] - r - float(rng.uniform(0.0, 0.8)), d * np.sin(ang)])
            spheres.append((c, r))
        return spheres

    def _make_poses(self, arc_deg: float) -> np.ndarray:  # -> [N, 4, 4]
        n, s = self.n_frames, self.motion_scale
        u = np.linspace(0.0, 1.0, n) if n > 1 else np.zeros(1)
        poses = []
        for k in u:
            if self.trajectory == "line":
                eye = np.array([0.3 * s * np.sin(2 * np.pi * k), -0.1, -2.0 * s + 2.5 * s * k])
                target = eye + np.array([0.15 * np.sin(np.pi * k), 0.05, 1.0])
            else:
                span = np.deg2rad(arc_deg) if self.trajectory == "orbit" else 2 * np.pi
                a = span * k
                radius = 1.6 * s
                eye = np.array([radius * np.sin(a), -0.2 + 0.1 * np.sin(2 * a), -radius * np.cos(a)])
                target = np.array([0.0, 0.6, 0.0])
            poses.append(_look_at(eye, target))
        return np.stack(poses)

    def __len__(self) -> int:
        return self.n_frames

    def timestamps(self) -> list[float]:
        return [i / self.fps for i in range(self.n_frames)]

    def ground_truth(self) -> Trajectory:
        return Trajectory(np.asarray(self.timestamps()), self._poses.copy())

    def __getitem__(self, index: int) -> Frame:
        if not -self.n_frames <= index < self.n_frames:
            raise IndexError(f"frame {index} out of range for {self.n_frames} frames")
        index = index % self.n_frames
        image, depth = self.render(self._poses[index])
        return Frame(
            index=index,
            timestamp=index / self.fps,
            image=image,
            intrinsics=self.intrinsics,
            depth=depth,
            T_world_cam_gt=self._poses[index].copy(),
        )

    def render(self, T_world_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ray-cast the scene from ``T_world_cam`` [4, 4] -> (image [H, W, 3], depth [H, W])."""
        w, h = self.intrinsics.width, self.intrinsics.height
        R, o = T_world_cam[:3, :3], T_world_cam[:3, 3]
        if np.any(np.abs(o) >= ROOM_HALF):
            raise SyntheticDatasetError(f"camera at {o} is outside the room {ROOM_HALF}")
        d = self._rays_cam @ R.T  # [N, 3] world directions with unit camera-z
        with np.errstate(divide="ignore", invalid="ignore"):
            t_hi = (ROOM_HALF - o) / d
            t_lo = (-ROOM_HALF - o) / d
        t_axes = np.where(d > 0, t_hi, t_lo)
        t_axes = np.where(np.abs(d) < 1e-12, np.inf, t_axes)
        axis = np.argmin(t_axes, axis=1)
        t = t_axes[np.arange(len(d)), axis]
        face = 2 * axis + (np.take_along_axis(d, axis[:, None], 1)[:, 0] > 0)
        color = np.zeros((len(d), 3), np.float32)
        P = o + t[:, None] * d
        for f in range(6):
            m = face == f
            if not m.any():
                continue
            a = f // 2
            u_ax, v_ax = [(1, 2), (0, 2), (0, 1)][a]
            uu = (P[m, u_ax] + ROOM_HALF[u_ax]) / (2 * ROOM_HALF[u_ax]) * (TEXTURE_SIZE - 1)
            vv = (P[m, v_ax] + ROOM_HALF[v_ax]) / (2 * ROOM_HALF[v_ax]) * (TEXTURE_SIZE - 1)
            color[m] = self._face_shade[f] * self._sample(self._textures[f], uu, vv)
        for (c, r), tex in zip(self._spheres, self._sphere_textures):
            oc = o - c
            b = d @ oc
            a2 = (d * d).sum(1)
            disc = b * b - a2 * (oc @ oc - r * r)
            hit = disc > 0
            ts = np.full(len(d), np.inf)
            ts[hit] = (-b[hit] - np.sqrt(disc[hit])) / a2[hit]
            m = (ts > 0) & (ts < t)
            if not m.any():
                continue
            t[m] = ts[m]
            n = (o + ts[m, None] * d[m] - c) / r
            lon = (np.arctan2(n[:, 0], n[:, 2]) + np.pi) / (2 * np.pi)
            lat = np.arccos(np.clip(n[:, 1], -1, 1)) / np.pi
            shade = 0.7 + 0.3 * np.clip(-n[:, 1], 0, 1)  # fixed "light from above": view-independent
            color[m] = shade[:, None].astype(np.float32) * self._sample(
                tex, lon * (tex.shape[1] - 1), lat * (tex.shape[0] - 1)
            )
        depth = t.reshape(h, w).astype(np.float32)  # rays have unit camera-z, so t is z depth
        return np.clip(color, 0, 1).reshape(h, w, 3), depth

    @staticmethod
    def _sample(tex: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:  # -> [N, 3]
        """Bilinear lookup of ``tex`` [S, S, 3] at texel coordinates ``u``, ``v`` [N] (clamped)."""
        hh, ww = tex.shape[:2]
        u = np.clip(u, 0, ww - 1.001)
        v = np.clip(v, 0, hh - 1.001)
        u0, v0 = u.astype(np.int64), v.astype(np.int64)
        fu, fv = (u - u0)[:, None], (v - v0)[:, None]
        top = tex[v0, u0] * (1 - fu) + tex[v0, u0 + 1] * fu
        bot = tex[v0 + 1, u0] * (1 - fu) + tex[v0 + 1, u0 + 1] * fu
        return (top * (1 - fv) + bot * fv).astype(np.float32)
