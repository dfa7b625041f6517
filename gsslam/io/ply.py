"""3D Gaussian Splatting PLY files (the layout of the original 3DGS code, read by common viewers).

One ``vertex`` element, binary little-endian float32 properties in this order::

    x y z nx ny nz f_dc_0 f_dc_1 f_dc_2 [f_rest_0 ...] opacity scale_0 scale_1 scale_2 rot_0 rot_1 rot_2 rot_3

``opacity`` is a logit, ``scale_*`` are log standard deviations, ``rot_*`` a (w, x, y, z) quaternion and
``f_dc = (rgb - 0.5) / 0.28209479``. Normals are written as zeros. Numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gsslam.errors import GsslamError
from gsslam.io.atomic import atomic_write_bytes

SH_C0 = 0.28209479177387814
_PLY_TYPES = {
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
    "uchar": "u1",
    "uint8": "u1",
    "char": "i1",
    "int8": "i1",
    "ushort": "u2",
    "uint16": "u2",
    "short": "i2",
    "int16": "i2",
    "uint": "u4",
    "uint32": "u4",
    "int": "i4",
    "int32": "i4",
}


class PlyError(GsslamError):
    """A PLY file is missing, not a 3DGS vertex PLY, or the arrays to write are inconsistent."""


@dataclass
class GaussianPly:
    """Gaussians in PLY parametrization (all float32): means [N, 3], quats_wxyz [N, 4], log_scales
    [N, 3], opacity_logits [N], f_dc [N, 3], f_rest [N, M] (M may be 0)."""

    means: np.ndarray
    quats_wxyz: np.ndarray
    log_scales: np.ndarray
    opacity_logits: np.ndarray
    f_dc: np.ndarray
    f_rest: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.means)
        if self.f_rest is None:
            self.f_rest = np.zeros((n, 0), np.float32)
        for name, cols in (("means", 3), ("quats_wxyz", 4), ("log_scales", 3), ("f_dc", 3)):
            a = np.asarray(getattr(self, name), dtype=np.float32)
            if a.shape != (n, cols):
                raise PlyError(f"{name} must be [{n}, {cols}], got {list(a.shape)}")
            setattr(self, name, a)
        self.opacity_logits = np.asarray(self.opacity_logits, dtype=np.float32).reshape(-1)
        if self.opacity_logits.shape != (n,):
            raise PlyError(f"opacity_logits must be [{n}], got {list(self.opacity_logits.shape)}")
        self.f_rest = np.asarray(self.f_rest, dtype=np.float32)
        if self.f_rest.ndim != 2 or len(self.f_rest) != n:
            raise PlyError(f"f_rest must be [{n}, M], got {list(self.f_rest.shape)}")

    def __len__(self) -> int:
        return len(self.means)

    @property
    def rgb(self) -> np.ndarray:  # [N, 3] in [0, 1]
        return np.clip(0.5 + SH_C0 * self.f_dc, 0.0, 1.0)


def _dtype(n_rest: int) -> np.dtype:
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(n_rest)]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    return np.dtype([(n, "<f4") for n in names])


def write_ply(path: str | Path, g: GaussianPly) -> int:
    """Write ``g`` as a binary little-endian 3DGS PLY; returns the file size in bytes."""
    path = Path(path)
    n_rest = g.f_rest.shape[1]
    data = np.zeros(len(g), dtype=_dtype(n_rest))
    for i, c in enumerate("xyz"):
        data[c] = g.means[:, i]
    for i in range(3):
        data[f"f_dc_{i}"] = g.f_dc[:, i]
        data[f"scale_{i}"] = g.log_scales[:, i]
    for i in range(n_rest):
        data[f"f_rest_{i}"] = g.f_rest[:, i]
    for i in range(4):
        data[f"rot_{i}"] = g.quats_wxyz[:, i]
    data["opacity"] = g.opacity_logits
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(g)}"]
    header += [f"property float {name}" for name in data.dtype.names]
    header += ["end_header"]
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, ("\n".join(header) + "\n").encode("ascii") + data.tobytes())
    return path.stat().st_size


def read_ply(path: str | Path) -> GaussianPly:
    """Read a 3DGS PLY (binary little-endian; extra properties are ignored)."""
    path = Path(path)
    if not path.is_file():
        raise PlyError(f"PLY file not found: {path}")
    raw = path.read_bytes()
    end = raw.find(b"end_header\n")
    if not raw.startswith(b"ply") or end < 0:
        raise PlyError(f"{path} is not a PLY file (no 'ply' magic or no end_header)")
    lines = raw[:end].decode("ascii", errors="replace").splitlines()
    fmt, n, props, element, before = None, None, [], None, 0
    for line in lines:
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "format":
            fmt = parts[1]
        elif parts[0] == "element":
            element = parts[1]
            if element == "vertex":
                n = int(parts[2])
            elif n is None:
                before += int(parts[2])
        elif parts[0] == "property" and element == "vertex":
            if parts[1] == "list":
                raise PlyError(f"{path}: list properties in the vertex element are not supported")
            if parts[1] not in _PLY_TYPES:
                raise PlyError(f"{path}: unknown PLY property type '{parts[1]}'")
            props.append((parts[2], "<" + _PLY_TYPES[parts[1]]))
    if before:
        raise PlyError(f"{path}: the vertex element must come first")
    if fmt != "binary_little_endian":
        raise PlyError(f"{path}: only binary_little_endian PLY is supported, got '{fmt}'")
    if n is None:
        raise PlyError(f"{path}: no vertex element")
    dt = np.dtype(props)
    body = raw[end + len(b"end_header\n") :]
    if len(body) < n * dt.itemsize:
        raise PlyError(f"{path}: truncated, {len(body)} bytes for {n} vertices of {dt.itemsize} bytes")
    data = np.frombuffer(body, dtype=dt, count=n)
    names = set(dt.names)
    need = [
        "x",
        "y",
        "z",
        "f_dc_0",
        "f_dc_1",
        "f_dc_2",
        "opacity",
        "scale_0",
        "scale_1",
        "scale_2",
        "rot_0",
        "rot_1",
        "rot_2",
        "rot_3",
    ]
    missing = [k for k in need if k not in names]
    if missing:
        raise PlyError(f"{path}: not a 3D Gaussian PLY, missing properties {missing}")
    col = lambda keys: np.stack([data[k].astype(np.float32) for k in keys], axis=1)  # noqa: E731
    rest = sorted((k for k in names if k.startswith("f_rest_")), key=lambda k: int(k.split("_")[-1]))
    return GaussianPly(
        means=col(["x", "y", "z"]),
        quats_wxyz=col([f"rot_{i}" for i in range(4)]),
        log_scales=col([f"scale_{i}" for i in range(3)]),
        opacity_logits=data["opacity"].astype(np.float32),
        f_dc=col([f"f_dc_{i}" for i in range(3)]),
        f_rest=col(rest) if rest else np.zeros((n, 0), np.float32),
    )


def write_points_ply(path: str | Path, xyz: np.ndarray, rgb: np.ndarray) -> int:
    """A coloured point cloud PLY (``x y z`` float32, ``red green blue`` uint8) as read by Open3D and
    nerfstudio's ``ply_file_path``; ``xyz`` [N, 3], ``rgb`` [N, 3] in 0..255. Returns the size in bytes."""
    xyz = np.asarray(xyz, dtype=np.float32).reshape(-1, 3)
    rgb = np.asarray(rgb).reshape(-1, 3)
    if len(rgb) != len(xyz):
        raise PlyError(f"{len(xyz)} points but {len(rgb)} colours")
    dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    data = np.zeros(len(xyz), dtype=dt)
    for i, c in enumerate("xyz"):
        data[c] = xyz[:, i]
    for i, c in enumerate(("red", "green", "blue")):
        data[c] = np.clip(np.round(rgb[:, i]), 0, 255)
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(xyz)}"]
    header += ["property float x", "property float y", "property float z"]
    header += ["property uchar red", "property uchar green", "property uchar blue", "end_header"]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as fh:
        fh.write(("\n".join(header) + "\n").encode("ascii"))
        fh.write(data.tobytes())
    return path.stat().st_size
