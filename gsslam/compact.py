"""Lossless compact storage of the per-keyframe arrays a run keeps until its end.

A run keeps every submap's point maps and confidences (loop closure, re-localization and the
depth priors read old submaps), so they set how memory grows with the length of a run. Two exact
packings, each checked bit for bit when it is made (else the array is kept as it was):

- **point maps** ``[n, h, w, 3]`` float32 whose X and Y are the back-projection of their Z through
  ``K`` (:func:`gsslam.geometry.depth_to_points`, as the RGB-D encoder makes them) are kept as Z only
  ``[n, h, w]`` and rebuilt on read: 3x smaller. Mono point maps (triangulated) stay whole.
- **codes**: a float32 array with at most 256 distinct values (the RGB-D confidence has three: 0,
  0.3, 1) is kept as uint8 indices into those values: 4x smaller.

:class:`PointMapField` and :class:`CodedField` are the descriptors that put these behind the
plain attributes of :class:`gsslam.types.SubmapEncoding`: readers see the same arrays either way.
"""

from __future__ import annotations

import numpy as np

from gsslam.geometry import depth_to_points

MAX_CODES = 256


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """True when ``a`` and ``b`` have the same shape, dtype and bytes (NaN payloads and -0.0 included)."""
    if a.shape != b.shape or a.dtype != b.dtype:
        return False
    bits = np.dtype(f"u{a.dtype.itemsize}")
    return bool(np.array_equal(a.view(bits), b.view(bits)))


def points_from_depth(K: np.ndarray, z: np.ndarray) -> np.ndarray:  # [3, 3], [n, h, w] -> [n, h, w, 3]
    """The float32 point maps of depth maps ``z`` (the RGB-D encoder's recipe)."""
    return np.stack([depth_to_points(K, d) for d in z]).astype(np.float32)


def pack_points(K: np.ndarray, points: np.ndarray) -> np.ndarray | None:  # [n, h, w, 3] -> [n, h, w]
    """Z of ``points`` (contiguous float32) when :func:`points_from_depth` gives ``points`` back exactly."""
    if points.dtype != np.float32 or points.ndim != 4 or points.shape[3] != 3 or not points.size:
        return None
    z = np.ascontiguousarray(points[..., 2])
    return z if same_bits(points_from_depth(K, z), points) else None


def pack_codes(a: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """``(codes uint8, values)`` with ``values[codes] == a`` bit for bit, when ``a`` has <= 256 values."""
    if a.dtype != np.float32 or not a.size:
        return None
    values, codes = np.unique(a.view(np.uint32), return_inverse=True)  # by bits: NaN, -0.0 kept apart
    if len(values) > MAX_CODES:
        return None
    return codes.reshape(a.shape).astype(np.uint8), values.view(np.float32)


class PointMapField:
    """A dataclass field holding ``[n, h, w, 3]`` point maps, whole or as Z (:func:`pack_points`).

    Stored on the instance as ``_<name>`` (whole, or None) and ``_<name>_z`` (packed, or None); the
    point maps' ``K`` is the instance's ``intrinsics.K``. A required field (no default).
    """

    def __set_name__(self, owner: type, name: str) -> None:
        self.whole, self.z = f"_{name}", f"_{name}_z"

    def __get__(self, obj, cls=None) -> np.ndarray:
        if obj is None:
            raise AttributeError(self.whole)  # tells dataclasses that the field has no default
        whole = obj.__dict__[self.whole]
        return whole if whole is not None else points_from_depth(obj.intrinsics.K, obj.__dict__[self.z])

    def __set__(self, obj, value: np.ndarray) -> None:
        obj.__dict__[self.whole], obj.__dict__[self.z] = value, None

    def depth(self, obj) -> np.ndarray:  # [n, h, w] the Z channel (a view of the stored array)
        z = obj.__dict__[self.z]
        return z if z is not None else obj.__dict__[self.whole][..., 2]

    def pack(self, obj) -> bool:
        """Keep only Z when that is exact; True when the field is packed afterwards."""
        whole = obj.__dict__[self.whole]
        if whole is None:
            return True
        z = pack_points(obj.intrinsics.K, whole)
        if z is not None:
            obj.__dict__[self.whole], obj.__dict__[self.z] = None, z
        return z is not None

    def nbytes(self, obj) -> int:
        whole = obj.__dict__[self.whole]
        return int(whole.nbytes if whole is not None else obj.__dict__[self.z].nbytes)


class CodedField:
    """A dataclass field holding a float32 array, whole or as uint8 codes (:func:`pack_codes`).

    Stored on the instance as ``_<name>`` (whole, or None), ``_<name>_codes`` and ``_<name>_values``.
    """

    def __set_name__(self, owner: type, name: str) -> None:
        self.whole, self.codes, self.values = f"_{name}", f"_{name}_codes", f"_{name}_values"

    def __get__(self, obj, cls=None) -> np.ndarray:
        if obj is None:
            raise AttributeError(self.whole)
        whole = obj.__dict__[self.whole]
        return whole if whole is not None else obj.__dict__[self.values][obj.__dict__[self.codes]]

    def __set__(self, obj, value: np.ndarray) -> None:
        d = obj.__dict__
        d[self.whole], d[self.codes], d[self.values] = value, None, None

    def pack(self, obj) -> bool:
        d = obj.__dict__
        if d[self.whole] is None:
            return True
        packed = pack_codes(d[self.whole])
        if packed is not None:
            d[self.whole], (d[self.codes], d[self.values]) = None, packed
        return packed is not None

    def nbytes(self, obj) -> int:
        d = obj.__dict__
        if d[self.whole] is not None:
            return int(d[self.whole].nbytes)
        return int(d[self.codes].nbytes + d[self.values].nbytes)
