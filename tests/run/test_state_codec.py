"""The checkpoint serializer: round trips keep values, dtypes and shared references; it refuses
objects and classes outside its registry, on both sides."""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np
import pytest
import torch

from gsslam.run.state_codec import StateCodecError, StateDecoder, StateEncoder, dumps


@dataclass
class Leaf:
    a: np.ndarray
    t: torch.Tensor
    rng: np.random.Generator
    gen: torch.Generator = field(default_factory=torch.Generator)


@dataclass
class Node:
    leaves: list
    by_key: dict
    res: object = None


@dataclass(frozen=True)
class Settings:
    x: int = 1


def _round_trip(obj, classes, resources=(), resolve=None):
    enc = StateEncoder(classes, resources)
    tree = json.loads(dumps(enc.encode(obj, "root")))
    return StateDecoder(classes, dict(enc.arrays), resolve or (lambda name: None)).decode(tree), enc


def test_round_trip_keeps_values_dtypes_and_sharing():
    rng = np.random.default_rng(5)
    rng.random(3)  # a generator part-way through its stream
    gen = torch.Generator().manual_seed(3)
    torch.rand(2, generator=gen)
    shared = np.arange(6, dtype=np.float32).reshape(2, 3)
    leaf = Leaf(shared, torch.nn.Parameter(torch.randn(4, 3)), rng, gen)
    settings = Settings()
    node = Node([leaf, leaf], {(1, 2): shared, 3: np.float64(0.5), "nan": float("nan")}, settings)
    back, enc = _round_trip(node, [Leaf, Node], (Settings,), {"root.res": settings}.get)
    assert back.leaves[0] is back.leaves[1] and back.by_key[(1, 2)] is back.leaves[0].a
    assert back.res is settings  # a resource comes from the caller, not from the file
    np.testing.assert_array_equal(back.leaves[0].a, shared)
    assert back.leaves[0].a.dtype == np.float32 and type(back.by_key[3]) is np.float64
    assert isinstance(back.leaves[0].t, torch.nn.Parameter) and back.leaves[0].t.requires_grad
    torch.testing.assert_close(back.leaves[0].t.detach(), leaf.t.detach(), rtol=0, atol=0)
    assert back.leaves[0].rng.random() == rng.random()  # the same stream continues
    assert torch.equal(torch.rand(3, generator=back.leaves[0].gen), torch.rand(3, generator=gen))
    assert np.isnan(back.by_key["nan"])


def test_unregistered_objects_are_refused_when_saving():
    with pytest.raises(StateCodecError, match="cannot store an object of type"):
        StateEncoder([Node]).encode(Node([object()], {}), "root")
    with pytest.raises(StateCodecError, match="arrays of Python objects"):
        StateEncoder([Node]).encode(Node([np.array([{}], dtype=object)], {}), "root")


def test_a_class_outside_the_registry_is_never_constructed():
    enc = StateEncoder([Node])
    tree = enc.encode(Node([], {}), "root")
    tree["cls"] = "subprocess.Popen"
    with pytest.raises(StateCodecError, match="not allowed"):
        StateDecoder([Node], {}, lambda n: None).decode(tree)


def test_8bit_images_are_stored_as_bytes_and_come_back_exactly():
    u8 = np.random.default_rng(0).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    img = u8.astype(np.float32) / np.float32(255.0)
    other = img.copy()
    other[0, 0, 0] += 1e-3  # not an 8-bit value: stored as float
    back, enc = _round_trip(Node([img, other], {}), [Node])
    assert [a.dtype for a in enc.arrays.values()] == [np.uint8, np.float32]
    for a, b in zip(back.leaves, [img, other]):
        assert a.dtype == np.float32 and np.array_equal(a, b)


def test_views_of_a_stored_array_are_stored_as_views():
    base = np.arange(2 * 3 * 4, dtype=np.float32).reshape(2, 3, 4) * np.float32(0.1)
    strided = base[:, 1, ::2]  # [2, 2]: a view with gaps
    alone = np.arange(5.0)[1:]  # its base is stored nowhere: stored whole
    back, enc = _round_trip([base, base[1], strided, alone], [])
    assert sum(a.nbytes for a in enc.arrays.values()) == base.nbytes + alone.nbytes  # no copies of base
    b0, b1, b2, b3 = back
    assert np.shares_memory(b1, b0) and np.shares_memory(b2, b0)
    for got, want in zip(back, [base, base[1], strided, alone], strict=True):
        assert got.dtype == want.dtype and got.strides == want.strides
        np.testing.assert_array_equal(got, want)
    b0[1, 1, 2] = -1.0  # one buffer again, as before saving
    assert b1[1, 2] == -1.0 and b2[1, 1] == -1.0


def test_a_view_cannot_reach_outside_its_array():
    enc = StateEncoder([])
    base = np.zeros(8, dtype=np.float32)
    tree = json.loads(dumps(enc.encode([base, base[2:]], "root")))
    tree["v"][1]["offset"] = 64  # past the end of the 32-byte array
    with pytest.raises(StateCodecError):
        StateDecoder([], dict(enc.arrays), lambda n: None).decode(tree)
