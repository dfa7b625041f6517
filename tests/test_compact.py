"""Compact storage of point maps and confidences: exact round trips, refusals, and what it saves."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gsslam.compact import pack_codes, pack_points, points_from_depth, same_bits
from gsslam.run.state_codec import StateDecoder, StateEncoder
from gsslam.types import CameraIntrinsics, SubmapEncoding

INTR = CameraIntrinsics(fx=267.7, fy=269.6, cx=160.05, cy=123.8, width=32, height=24)


def _depths(rng, n=3) -> np.ndarray:  # [n, h, w] float32 metres with holes
    z = rng.uniform(0.4, 4.0, (n, INTR.height, INTR.width)).astype(np.float32)
    z[rng.random(z.shape) < 0.2] = np.nan
    return z


def _rgbd_encoding(rng, n=3) -> SubmapEncoding:
    """As the RGB-D encoder makes them: back-projected depth, confidence in {0, 0.3, 1}."""
    z = _depths(rng, n)
    conf = np.where(np.isfinite(z), np.where(rng.random(z.shape) < 0.1, 0.3, 1.0), 0.0).astype(np.float32)
    return SubmapEncoding(
        list(range(n)), np.tile(np.eye(4), (n, 1, 1)), points_from_depth(INTR.K, z), conf, INTR
    )


def test_points_pack_to_depth_and_back_bit_for_bit():
    rng = np.random.default_rng(0)
    z = _depths(rng)
    points = points_from_depth(INTR.K, z)
    packed = pack_points(INTR.K, points)
    assert packed is not None and packed.flags.c_contiguous
    assert same_bits(packed, z)
    assert same_bits(points_from_depth(INTR.K, packed), points)


def test_points_that_are_not_back_projected_depth_are_not_packed():
    rng = np.random.default_rng(1)
    points = points_from_depth(INTR.K, _depths(rng))
    tri = points.copy()
    v, u = np.argwhere(np.isfinite(tri[1, ..., 2]))[0]
    tri[1, v, u, 0] = np.nextafter(tri[1, v, u, 0], np.float32(np.inf))  # one X off by one ulp (mono)
    assert pack_points(INTR.K, tri) is None
    other_K = INTR.scaled(2.0).K
    assert pack_points(other_K, points) is None  # another camera's rays
    assert pack_points(INTR.K, points.astype(np.float64)) is None


def test_codes_keep_nan_and_signed_zero_and_refuse_many_values():
    a = np.array([[0.0, -0.0, 0.3], [1.0, np.nan, 0.3]], dtype=np.float32)
    codes, values = pack_codes(a)
    assert codes.dtype == np.uint8 and len(values) == 4 + 0 + 1  # 0, -0, 0.3, 1, NaN
    assert same_bits(values[codes], a)
    assert pack_codes(np.linspace(0, 1, 257, dtype=np.float32)) is None  # 257 distinct values
    assert pack_codes(np.linspace(0, 1, 256, dtype=np.float32)) is not None


def test_packed_encoding_reads_the_same_arrays_and_is_5x_smaller():
    rng = np.random.default_rng(2)
    enc = _rgbd_encoding(rng)
    P, C = enc.points_cam.copy(), enc.confidence.copy()
    before = enc.nbytes
    assert enc.pack()
    assert same_bits(enc.points_cam, P) and same_bits(enc.confidence, C)
    assert same_bits(enc.depths, np.ascontiguousarray(P[..., 2]))
    assert enc.depths.flags.c_contiguous  # keyframe depths can be views of it
    # z float32 + confidence uint8 (+ 3 code values) instead of xyz + confidence float32: 16 / 5 bytes
    assert before / enc.nbytes == pytest.approx(16 / 5, rel=0.01)
    assert enc.pack()  # packing twice does nothing
    assert same_bits(dataclasses.replace(enc, meta={"a": 1}).points_cam, P)


def test_an_encoding_that_cannot_be_packed_stays_whole():
    rng = np.random.default_rng(3)
    enc = _rgbd_encoding(rng)
    pts = enc.points_cam.copy()
    pts[..., :2] *= np.float32(1.01)  # triangulated maps (mono): X, Y not from Z
    conf = rng.uniform(0, 1, pts.shape[:3]).astype(np.float32)  # continuous confidences
    mono = dataclasses.replace(enc, points_cam=pts, confidence=conf)
    nbytes = mono.nbytes
    assert not mono.pack()
    assert mono.nbytes == nbytes and same_bits(mono.points_cam, pts) and same_bits(mono.confidence, conf)


def test_a_packed_encoding_survives_the_checkpoint_codec_packed():
    rng = np.random.default_rng(4)
    enc = _rgbd_encoding(rng)
    P, C = enc.points_cam.copy(), enc.confidence.copy()
    enc.pack()
    codec = StateEncoder([SubmapEncoding, CameraIntrinsics])
    tree = codec.encode(enc)
    assert sum(a.nbytes for a in codec.arrays.values()) < 1.05 * enc.nbytes + 2000  # T_local_cam aside
    back = StateDecoder([SubmapEncoding, CameraIntrinsics], codec.arrays, resolve=None).decode(tree)
    assert back.nbytes == enc.nbytes
    assert same_bits(back.points_cam, P) and same_bits(back.confidence, C)
